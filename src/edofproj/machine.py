"""The machine a timing ran on: the CPU's vector instruction sets, named beside every figure.

A CPU's speed for this project's work depends mostly on its widest vector unit and on whether it
computes in bfloat16 natively: PyTorch runs the networks in bf16 autocast only where the CPU has
AVX-512-BF16 or AMX (``edofproj.training``), and in float32 elsewhere (AVX2 only: most laptops).
The flags are read from ``/proc/cpuinfo`` (Linux, the ``flags`` line ``lscpu`` prints); elsewhere
the CPU is named ``unknown``.

**Measuring an AVX2-only CPU on a wider one.** PyTorch's own kernels follow
``ATEN_CPU_CAPABILITY`` (``avx2``, ``avx512``, ``default``) and oneDNN's convolutions follow
``ONEDNN_MAX_CPU_ISA`` (``AVX2``, ``AVX512_CORE``, ``AVX512_CORE_BF16``, ``AVX512_CORE_AMX``, ...);
MKL's matrix products follow ``MKL_ENABLE_INSTRUCTIONS``. Set to AVX2, the three make an AVX-512
machine run the code paths of an AVX2-only CPU (its clock and caches stay its own).
:func:`usable_flags` removes what they forbid, so :func:`instruction_sets` names the instruction sets a
timing really used and :func:`native_bf16` (and with it ``train.mixed_precision: auto``) chooses
float32 there, as on the AVX2 CPU.

    ATEN_CPU_CAPABILITY=avx2 ONEDNN_MAX_CPU_ISA=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 python benchmarks/...
"""

from __future__ import annotations

import os
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


#: The instruction-set limits read from the environment: ``(variable, value, cpuinfo flags it forbids)``; a
#: value not listed forbids nothing. ``avx512*`` covers every AVX-512 extension.
_AVX512 = ("avx512*", "amx_bf16")
ISA_LIMITS: dict[str, dict[str, tuple[str, ...]]] = {
    "ATEN_CPU_CAPABILITY": {"avx2": _AVX512, "default": ("avx2", "fma", *_AVX512)},
    "ONEDNN_MAX_CPU_ISA": {
        "avx2": _AVX512,
        "avx2_vnni": _AVX512,
        "avx512_core": ("avx512_bf16", "amx_bf16"),
        "avx512_core_vnni": ("avx512_bf16", "amx_bf16"),
        "avx512_core_bf16": ("amx_bf16",),
    },
    "MKL_ENABLE_INSTRUCTIONS": {"avx2": _AVX512},
}


def isa_limits(environ: dict[str, str] | None = None) -> list[str]:
    """The instruction-set limits set in ``environ`` (default: this process's), as ``VARIABLE=value``."""
    environ = dict(os.environ) if environ is None else environ
    return [f"{name}={environ[name]}" for name in ISA_LIMITS if environ.get(name, "").strip()]


def usable_flags(flags: set[str] | None = None, environ: dict[str, str] | None = None) -> set[str]:
    """``flags`` (default: this CPU's) less the instruction sets the environment's limits forbid
    (:data:`ISA_LIMITS`, module docstring)."""
    flags = set(cpu_flags() if flags is None else flags)
    environ = dict(os.environ) if environ is None else environ
    for name, limits in ISA_LIMITS.items():
        for pattern in limits.get(environ.get(name, "").strip().lower(), ()):
            if pattern.endswith("*"):
                flags = {f for f in flags if not f.startswith(pattern[:-1])}
            else:
                flags.discard(pattern)
    return flags


def native_bf16(flags: set[str] | None = None) -> bool:
    """Whether the CPU computes bfloat16 natively (AVX-512-BF16 or AMX), within the environment's
    instruction-set limits when ``flags`` is not given (:func:`usable_flags`)."""
    flags = usable_flags() if flags is None else flags
    return bool(flags & {"avx512_bf16", "amx_bf16"})


def instruction_sets(flags: set[str] | None = None) -> str:
    """``"x86_64 AVX2 FMA AVX-512 ..."``: the machine and the instruction sets of :data:`INSTRUCTION_SETS` it has,
    ending in ``"(no native bf16)"`` where it lacks AVX-512-BF16 and AMX. Without ``flags``, this CPU's
    within the environment's limits, which are then named: ``"x86_64 AVX2 FMA (no native bf16; limited by
    ATEN_CPU_CAPABILITY=avx2 ...; the CPU has AVX2 FMA AVX-512 ...)"``."""
    limits = isa_limits() if flags is None else []
    all_flags = cpu_flags() if flags is None else flags
    if not all_flags:
        return f"{platform.machine() or 'unknown'} (CPU flags unknown)"
    flags = usable_flags(all_flags) if limits else all_flags
    names = [name for flag, name in INSTRUCTION_SETS if flag in flags]
    notes = [] if native_bf16(flags) else ["no native bf16"]
    if limits and flags != all_flags:
        has = " ".join(name for flag, name in INSTRUCTION_SETS if flag in all_flags)
        notes.append(f"limited by {' '.join(limits)}; the CPU has {has}")
    suffix = f" ({'; '.join(notes)})" if notes else ""
    return f"{platform.machine()} {' '.join(names) or 'no AVX2'}{suffix}"
