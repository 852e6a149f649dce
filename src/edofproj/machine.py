"""The machine a timing ran on: the CPU's vector instruction sets, named beside every figure.

A CPU's speed for this project's work depends mostly on its widest vector unit and on whether it
computes in bfloat16 natively: PyTorch runs the networks in bf16 autocast only where the CPU has
AVX-512-BF16 or AMX (``edofproj.training``), and in float32 elsewhere (AVX2 only: most laptops).
The flags are read from ``/proc/cpuinfo`` (Linux, the ``flags`` line ``lscpu`` prints); elsewhere
the CPU is named ``unknown``.
"""

from __future__ import annotations

import platform
from pathlib import Path

#: ``(cpuinfo flag, name)`` of the instruction sets reported, narrowest first.
INSTRUCTION_SETS = (
    ("avx2", "AVX2"),
    ("fma", "FMA"),
    ("avx512f", "AVX-512"),
    ("avx512_vnni", "AVX-512-VNNI"),
    ("avx512_bf16", "AVX-512-BF16"),
    ("amx_bf16", "AMX-BF16"),
)


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The flags of the first processor in ``cpuinfo`` (default: ``/proc/cpuinfo``); empty if unreadable."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
        except OSError:
            return set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return set(value.split())
    return set()


def native_bf16(flags: set[str] | None = None) -> bool:
    """Whether the CPU computes bfloat16 natively (AVX-512-BF16 or AMX)."""
    flags = cpu_flags() if flags is None else flags
    return bool(flags & {"avx512_bf16", "amx_bf16"})


def instruction_sets(flags: set[str] | None = None) -> str:
    """``"x86_64 AVX2 FMA AVX-512 ..."``: the machine and the instruction sets of :data:`INSTRUCTION_SETS` it has,
    ending in ``"(no native bf16)"`` where it lacks AVX-512-BF16 and AMX."""
    flags = cpu_flags() if flags is None else flags
    if not flags:
        return f"{platform.machine() or 'unknown'} (CPU flags unknown)"
    names = [name for flag, name in INSTRUCTION_SETS if flag in flags]
    suffix = "" if native_bf16(flags) else " (no native bf16)"
    return f"{platform.machine()} {' '.join(names) or 'no AVX2'}{suffix}"
