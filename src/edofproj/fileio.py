"""Atomic file writing: write to a temporary file beside the target, then rename.

A command that fails half-way therefore never leaves a half-written output file. A process
killed half-way (``kill -9``, power loss) leaves its temporary file ``.<name>.tmp-XXXXXXXX<suffix>``
behind; :func:`remove_stale_temp_files` removes those of a directory the caller has locked
(:mod:`edofproj.locking`), so no other process can be writing them.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import shutil
import tempfile
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from .errors import DiskFullError, EdofprojError, RecoveryWarning
from .limits import check_memory

TEMP_MARKER = ".tmp-"
#: How the lock files of :mod:`edofproj.locking` end (``.edofproj.lock``; that module imports this one).
LOCK_FILE_SUFFIX = ".edofproj.lock"
#: Temporary files of :func:`atomic_path`: ``.<target>.tmp-<8 random chars><suffix>`` (and the
#: ``.<target>.<8 random chars><suffix>`` names of earlier versions).
TEMP_PATTERN = re.compile(r"^\.(?P<target>.+?)\.(?:tmp-)?[a-z0-9_]{8}(?:\.[A-Za-z0-9]+)+$")


#: The ``errno`` values of a full disk: no space left, and the user's disk quota exceeded.
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is an :class:`OSError` of a full disk (:data:`DISK_FULL_ERRNOS`)."""
    return isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS


def _mount_point(path: Path) -> Path:
    """The mount point of the file system that holds ``path`` (its nearest existing folder's)."""
    folder = Path(os.path.abspath(path))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    while not os.path.ismount(folder) and folder != folder.parent:
        folder = folder.parent
    return folder


def disk_full_error(path: str | os.PathLike, kept: str) -> DiskFullError:
    """The one line of a write to ``path`` that the full disk stopped: the disk (its mount point and
    the space left on it) and ``kept``, what the failed write left as it was."""
    disk = _mount_point(Path(path))
    try:
        free = f", {shutil.disk_usage(disk).free / 1e6:.1f} MB free"
    except OSError:
        free = ""
    return DiskFullError(f"cannot write '{os.fspath(path)}': the disk of '{disk}' is full{free}; {kept}")


def kept_phrase(target: str | os.PathLike) -> str:
    """What a failed write of ``target`` left: the previous file or folder, or nothing."""
    return f"the previous '{os.fspath(target)}' is kept" if Path(target).exists() else "nothing was written"


def user_mode(mode: int = 0o777) -> int:
    """``mode`` less the process's umask: the permissions of a file (``0o666``) or folder (``0o777``)
    the user creates (``mkstemp``/``mkdtemp`` make private ones, 0600/0700, that an output must not keep)."""
    umask = os.umask(0)
    os.umask(umask)
    return mode & ~umask


def _write_error(target: Path, exc: OSError) -> EdofprojError:
    """A one-line error about writing ``target`` (never the temporary file's name)."""
    if is_disk_full(exc):
        return disk_full_error(target, kept_phrase(target))
    reason = exc.strerror or type(exc).__name__
    hint = f": is '{target.parent}' writable?" if isinstance(exc, PermissionError) else ""
    return EdofprojError(f"cannot write '{target}': {reason}{hint}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path``.

    The temporary file keeps the target's suffix (so libraries that pick a format from
    the extension still work). On any exception the temporary file is removed and the
    target is left untouched.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{target.name}{TEMP_MARKER}",
            suffix=suffix if suffix is not None else (target.suffix or ".tmp"),
            dir=target.parent,
        )
    except OSError as exc:
        raise _write_error(target, exc) from None
    os.close(fd)
    os.chmod(tmp, user_mode(0o666))  # mkstemp creates 0600; outputs get the usual permissions
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        try:
            os.replace(tmp_path, target)
        except OSError as exc:
            raise _write_error(target, exc) from None
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        if is_disk_full(exc):
            raise disk_full_error(target, kept_phrase(target)) from None
        raise


def save_npz_atomic(path: str | os.PathLike, **arrays) -> None:
    """``numpy.savez_compressed`` written atomically (no ``.npz`` appended to the name)."""
    with atomic_path(path, suffix=".npz.tmp") as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)


def read_arrays(path: str | os.PathLike, what: str = "file") -> dict[str, np.ndarray]:
    """All arrays of a ``.npz`` archive (or the one array of a ``.npy`` file, as ``{"": array}``),
    read eagerly, with one-line errors that name ``what`` and the file: missing, not a NumPy
    file, truncated or damaged, or holding Python objects (never loaded: they could run code)."""
    path = Path(path)
    if not path.is_file():
        raise EdofprojError(f"{what} '{path}' does not exist" + (" (it is a directory)" if path.is_dir() else ""))
    try:
        with open(path, "rb") as handle:
            head = handle.read(6)
    except OSError as exc:
        raise EdofprojError(f"cannot read {what} '{path}': {exc.strerror or exc}") from None
    if not (head.startswith(b"PK") or head.startswith(b"\x93NUMPY")):
        raise EdofprojError(f"{what} '{path}' is not a NumPy .npz/.npy file")
    check_array_headers(path, what)
    try:
        loaded = np.load(path, allow_pickle=False)
        if isinstance(loaded, np.ndarray):
            return {"": loaded}
        with loaded:
            return {name: loaded[name] for name in loaded.files}
    except ValueError as exc:
        if "pickle" in str(exc):
            raise EdofprojError(
                f"{what} '{path}' holds Python objects, not plain arrays: it was not written by edofproj"
            ) from None
        raise EdofprojError(f"{what} '{path}' is truncated or damaged") from None
    except (OSError, EOFError, KeyError, zipfile.BadZipFile, zlib.error):
        raise EdofprojError(f"{what} '{path}' is truncated or damaged") from None


def read_tagged_arrays(
    path: str | os.PathLike, what: str, format_name: str, keys: Iterable[str], make: str
) -> dict[str, np.ndarray]:
    """:func:`read_arrays` of an archive written with ``format=format_name``: one line when the
    tag is missing or another (``make`` says how to make one) or when one of ``keys`` is missing."""
    data = read_arrays(path, what=what)
    source = f"{what} '{path}'"
    if "format" not in data or str(data["format"]) != format_name:
        raise EdofprojError(f"{source} is not a {what} ({make})")
    missing = [key for key in keys if key not in data]
    if missing:
        raise EdofprojError(f"{source} lacks {', '.join(missing)}")
    return data


def read_single_numeric_array(path: str | os.PathLike, what: str, label: str, holds: str) -> np.ndarray:
    """The one numeric array of ``path`` (a ``.npy``, or an ``.npz`` of one member): one line, naming the
    file as ``label``, when it holds another count of arrays (``holds`` says what it should hold) or a
    non-numeric one. Its shape is the caller's to check."""
    arrays = read_arrays(path, what=what)
    if len(arrays) != 1:
        raise EdofprojError(f"{label} holds {len(arrays)} arrays; {holds}")
    values = next(iter(arrays.values()))
    if values.dtype.kind not in "fiu":
        raise EdofprojError(f"{label} is not a numeric array ({values.dtype})")
    return values


def _header(handle, what: str, path: Path, member: str = "") -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype a ``.npy`` header at ``handle`` declares (nothing else is read)."""
    where = f"{what} '{path}'" + (f" (array '{member}')" if member else "")
    try:
        version = np.lib.format.read_magic(handle)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
    except ValueError as exc:
        if "pickle" in str(exc) or "object" in str(exc).lower():
            raise EdofprojError(
                f"{where} holds Python objects, not plain arrays: it was not written by edofproj"
            ) from None
        raise EdofprojError(f"{where} has a damaged header") from None
    except (OSError, EOFError):
        raise EdofprojError(f"{where} is truncated or damaged") from None
    return tuple(int(n) for n in shape), dtype


def array_bytes(shape: tuple[int, ...], dtype: np.dtype) -> int:
    """Bytes of an array of ``shape`` and ``dtype`` (Python integers: no overflow)."""
    return math.prod(shape) * int(dtype.itemsize)


def check_array_headers(path: str | os.PathLike, what: str = "file") -> None:
    """Refuse in one line, before anything is allocated, a ``.npy`` file (or a member of a ``.npz``
    archive) whose header declares an array larger than the memory available
    (:func:`edofproj.limits.check_memory`) or larger than the bytes the file holds (truncated)."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            if handle.read(2) != b"PK":
                handle.seek(0)
                shape, dtype = _header(handle, what, path)
                declared = {"": (shape, dtype, path.stat().st_size - handle.tell())}
            else:
                declared = {}
                with zipfile.ZipFile(path) as archive:
                    for info in archive.infolist():
                        if info.filename.endswith(".npy"):
                            with archive.open(info) as stream:
                                shape, dtype = _header(stream, what, path, info.filename[:-4])
                                declared[info.filename[:-4]] = (shape, dtype, info.file_size - stream.tell())
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error):
        raise EdofprojError(f"{what} '{path}' is truncated or damaged") from None
    for member, (shape, dtype, stored) in declared.items():
        needed = array_bytes(shape, dtype)
        name = f"{what} '{path}'" + (f" (array '{member}')" if member else "")
        if dtype.hasobject:
            continue  # refused by np.load(allow_pickle=False): "holds Python objects"
        check_memory(
            needed,
            f"{name} (its header declares an array of shape {shape}, {dtype})",
            "is it the file you meant? (a damaged header declares any size)",
        )
        if needed > stored:
            raise EdofprojError(
                f"{name} is truncated: its header declares {needed} bytes of shape {shape}, the file holds {stored}"
            )


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write a binary file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def remove_stale_temp_files(
    directory: str | os.PathLike, recursive: bool = False, target: str | None = None
) -> list[Path]:
    """Delete the temporary files that interrupted atomic writes left in ``directory`` (and, with
    ``recursive``, its subdirectories); returns them. Call it only while holding the directory's
    lock (:mod:`edofproj.locking`): another writer's temporary file would be deleted too. With
    ``target`` (a file name), only the temporary files of that file (hold that file's lock)."""
    root = Path(directory)
    if not root.is_dir():
        return []
    candidates = root.rglob(".*") if recursive else root.glob(".*")
    removed = []
    for path in sorted(candidates):
        match = TEMP_PATTERN.match(path.name)
        if path.name.endswith(LOCK_FILE_SUFFIX):
            continue  # a lock file beside a folder or file (``.<name>.edofproj.lock``) is never a temporary file
        if target is not None and (match is None or match.group("target") != target):
            continue
        if path.is_file() and not path.is_symlink() and match:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed


def remove_stale_folders(folders: Iterable[Path], what: str, stacklevel: int = 2) -> list[Path]:
    """Delete the staging folders that an interrupted writer left (the real folders among ``folders``,
    never a link) and warn once with a :class:`~edofproj.errors.RecoveryWarning`
    ``removed N <what>``; returns them. Call it only while holding the output's lock
    (:mod:`edofproj.locking`): no live writer owns them then. ``stacklevel`` as for
    :func:`warnings.warn`, counted from the caller."""
    stale = [p for p in folders if p.is_dir() and not p.is_symlink()]
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    if stale:
        warnings.warn(f"removed {len(stale)} {what}", RecoveryWarning, stacklevel=stacklevel + 1)
    return stale
