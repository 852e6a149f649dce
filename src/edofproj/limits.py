"""Memory limits checked before allocating: refuse a request the machine cannot hold, with a message.

Commands estimate the memory a step will need (PSF window and pupil samples, image and pattern
sizes; the estimates live beside the code that allocates) and call :func:`check_memory` first.
A request larger than the memory available is refused with one line saying what it would need,
what is available and what to change, instead of the kernel killing the process (or every
process on the machine) half-way.

The memory available is the smallest of

* ``MemAvailable`` of ``/proc/meminfo`` (free memory plus reclaimable caches), or the free
  physical pages from ``os.sysconf`` where there is no ``/proc``;
* the free room of this process's cgroup (``memory.max - memory.current``, cgroup v2; or the v1
  ``memory.limit_in_bytes - memory.usage_in_bytes``), the limit of a container or job slot;
* the room left below this process's address-space limit (``ulimit -v``), when it has one;
* ``EDOFPROJ_MEMORY_BYTES`` when set: the memory edofproj may use (e.g. on a shared machine).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from .errors import EdofprojError

ENV_LIMIT = "EDOFPROJ_MEMORY_BYTES"


class MemoryLimitError(EdofprojError):
    """A request would need more memory than the machine has available."""


def format_bytes(count: float) -> str:
    """``1536 -> '1.5 KiB'``, binary units."""
    value = float(count)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(value) < 1024 or unit == "PiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} PiB"  # pragma: no cover - the loop returns


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _sysconf_available() -> int | None:
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _cgroup_room() -> int | None:
    """Free room below this process's cgroup memory limit, or None without a limit."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    rooms = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        relative = parts[2].lstrip("/")
        if parts[1] == "":  # cgroup v2
            base = Path("/sys/fs/cgroup") / relative
            limit, usage = _read_int(base / "memory.max"), _read_int(base / "memory.current")
            if limit is None:  # inside a namespace the process's own group is the root
                limit, usage = (
                    _read_int(Path("/sys/fs/cgroup/memory.max")),
                    _read_int(Path("/sys/fs/cgroup/memory.current")),
                )
        elif "memory" in parts[1].split(","):
            base = Path("/sys/fs/cgroup/memory")
            limit = _read_int(base / relative / "memory.limit_in_bytes") or _read_int(base / "memory.limit_in_bytes")
            usage = _read_int(base / relative / "memory.usage_in_bytes") or _read_int(base / "memory.usage_in_bytes")
        else:
            continue
        if limit is not None and limit < 2**60:
            rooms.append(max(limit - (usage or 0), 0))
    return min(rooms) if rooms else None


def _address_space_room() -> int | None:
    """``RLIMIT_AS`` (``ulimit -v``) less this process's current virtual size, or None without a limit."""
    try:
        import resource  # optional: POSIX only
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return max(soft - int(line.split()[1]) * 1024, 0)
    except (OSError, ValueError, IndexError):
        pass
    return soft


def available_memory_bytes() -> int | None:
    """The memory this process may still allocate (module docstring), or None when unknown."""
    candidates = [_meminfo_available() or _sysconf_available(), _cgroup_room(), _address_space_room()]
    override = os.environ.get(ENV_LIMIT, "").strip()
    if override:
        try:
            candidates.append(int(float(override)))
        except ValueError:
            raise EdofprojError(f"{ENV_LIMIT}={override!r} must be a number of bytes") from None
    known = [c for c in candidates if c is not None]
    return min(known) if known else None


def available_device_memory_bytes(device=None) -> int | None:
    """Free memory of a CUDA ``device`` (``torch.cuda.mem_get_info``); for the CPU (or None), the
    memory of :func:`available_memory_bytes`."""
    if device is not None and getattr(device, "type", str(device).split(":")[0]) == "cuda":
        import torch  # start-up: the foundation layer (config, limits) loads without torch

        free, _ = torch.cuda.mem_get_info(device)
        override = available_memory_bytes() if os.environ.get(ENV_LIMIT, "").strip() else None
        return min(int(free), override) if override is not None else int(free)
    return available_memory_bytes()


def check_memory(needed_bytes: float, what: str, change: str, device=None) -> None:
    """Raise :class:`MemoryLimitError` when ``needed_bytes`` exceeds the memory available (on
    ``device``: a CUDA device's free memory, else the machine's).

    ``what`` names the request (``"a 100001-px PSF window"``), ``change`` what to do instead
    (``"use a smaller psf.window"``). Unknown available memory: nothing is checked."""
    if not math.isfinite(needed_bytes):
        raise MemoryLimitError(f"{what} needs an unbounded amount of memory: {change}")
    available = available_device_memory_bytes(device)
    if available is not None and needed_bytes > available:
        where = "GPU memory" if device is not None and "cuda" in str(device) else "memory"
        raise MemoryLimitError(
            f"{what} needs about {format_bytes(needed_bytes)} of {where}, more than the "
            f"{format_bytes(available)} available: {change}"
        )
