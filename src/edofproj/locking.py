"""Directory locks: one writer per run directory, capture folder or evaluation output.

A process that writes a directory holds its lock file ``<dir>/.edofproj.lock`` for the whole
time it writes. The file names the owner (JSON: ``pid``, ``host``, ``command``, ``started``,
``process_start``) and is locked with ``fcntl.flock``, which the kernel releases when the
owner exits in any way (``kill -9`` included). So:

* a second writer finds the ``flock`` held and is refused with one line naming the owner;
* a lock file left by a dead process (its ``flock`` is free) is taken over, with a
  :class:`~edofproj.errors.RecoveryWarning` naming the process that left it;
* on platforms without ``fcntl`` the owner's PID (and its start time, against PID reuse) is
  checked instead.

Use it as a context manager::

    with directory_lock(run_dir, "edofproj train", "--out"):
        ...  # write into run_dir

A directory that is written elsewhere and then renamed into place (a capture folder written by
:func:`edofproj.procams.capture_io.atomic_folder`) is locked with ``beside=True``: the lock file
is then ``<parent>/.<name>.edofproj.lock``, which the rename does not carry away.

Lock files start with a dot; :func:`is_lock_file` tells them apart (e.g. the check that a new
run directory is empty skips them). A lock file is removed when its lock is released.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Iterator

from .errors import EdofprojError, RecoveryWarning
from .fileio import LOCK_FILE_SUFFIX, disk_full_error, is_disk_full

try:
    import fcntl  # optional: POSIX only (no file locks on Windows)
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = LOCK_FILE_SUFFIX


class DirectoryLockedError(EdofprojError):
    """Another live process holds the directory's lock."""


def is_lock_file(path: str | os.PathLike) -> bool:
    """True for a directory lock file (skip it when listing a directory's contents)."""
    name = Path(path).name
    return name == LOCK_NAME or (name.startswith(".") and name.endswith(LOCK_NAME))


def _process_start_ticks(pid: int) -> int | None:
    """The start time of process ``pid`` in clock ticks since boot (Linux), or None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) may hold spaces and parentheses: split after its closing ')'
    fields = stat[stat.rfind(")") + 2 :].split()
    try:
        return int(fields[19])  # field 22 of the whole line
    except (IndexError, ValueError):
        return None


def _process_alive(pid: int, start_ticks: int | None) -> bool:
    """Whether process ``pid`` on this host still runs (and is the same process, when its start
    time is known)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by another user
    if start_ticks is not None:
        now = _process_start_ticks(pid)
        if now is not None and now != start_ticks:
            return False  # the PID was reused by another process
    return True


def _describe(owner: dict[str, Any]) -> str:
    what = owner.get("command") or "edofproj"
    since = owner.get("started")
    since_text = f", since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(since))}" if since else ""
    return f"{what} (PID {owner.get('pid', '?')} on host {owner.get('host', '?')}{since_text})"


def read_lock_owner(directory: str | os.PathLike, beside: bool = False) -> dict[str, Any] | None:
    """The owner recorded in ``directory``'s lock file, or None when there is none or it is unreadable."""
    return DirectoryLock(directory, beside=beside)._read_owner()


def _read_owner_file(path: Path) -> dict[str, Any] | None:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError:
        return None
    try:
        owner = json.loads(text)
    except ValueError:
        return None
    return owner if isinstance(owner, dict) else None


class DirectoryLock:
    """The write lock of one directory (module docstring). ``what`` names the writer in messages
    (e.g. ``"train"``); ``option`` names the user's option for the directory (e.g. ``"--out"``).
    ``of_file``: the path is a file written in place (:func:`sole_file_writer`; the lock sits beside it)."""

    def __init__(
        self,
        directory: str | os.PathLike,
        what: str = "edofproj",
        option: str = "",
        beside: bool = False,
        of_file: bool = False,
    ) -> None:
        self.directory = Path(directory)
        self.beside = beside or of_file
        self.of_file = of_file
        self.path = (
            self.directory.parent / f".{self.directory.name}{LOCK_NAME}" if self.beside else self.directory / LOCK_NAME
        )
        self.what = what
        self.option = option
        self._fd: int | None = None
        self._created = False

    @property
    def held(self) -> bool:
        return self._fd is not None

    def _read_owner(self) -> dict[str, Any] | None:
        return _read_owner_file(self.path)

    def _refuse(self, owner: dict[str, Any] | None) -> DirectoryLockedError:
        who = _describe(owner) if owner else "another edofproj process"
        name = f"{self.option} '{self.directory}'" if self.option else f"'{self.directory}'"
        return DirectoryLockedError(f"{name} is being written by {who}: wait for it to finish or use another directory")

    def _owner_record(self) -> dict[str, Any]:
        pid = os.getpid()
        return {
            "pid": pid,
            "host": socket.gethostname(),
            "command": self.what,
            "started": time.time(),
            "process_start": _process_start_ticks(pid),
            "argv": sys.argv[1:][:20],
        }

    def acquire(self) -> "DirectoryLock":
        """Take the lock (creating the directory); raise :class:`DirectoryLockedError` when a live
        process holds it; take over, with a warning, a lock left by a dead one."""
        if self._fd is not None:
            return self
        if self.directory.exists() and not self.directory.is_dir() and not self.of_file:
            raise EdofprojError(f"'{self.directory}' exists and is not a directory")
        try:
            if self.beside:
                self.directory.parent.mkdir(parents=True, exist_ok=True)
            else:
                self._created = not self.directory.exists()
                self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise EdofprojError(f"cannot create '{self.directory}': {exc.strerror or exc}") from None
        for _ in range(20):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise EdofprojError(
                    f"cannot lock '{self.directory}': {exc.strerror or exc} (is the directory writable?)"
                ) from None
            if fcntl is not None:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    os.close(fd)
                    raise self._refuse(self._read_owner()) from None
                # the file may have been released and removed between open and flock: retry on a fresh one
                try:
                    same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
                except FileNotFoundError:
                    same = False
                if not same:
                    os.close(fd)
                    continue
            previous = self._read_owner()
            if previous is not None:
                local = previous.get("host") == socket.gethostname()
                pid = int(previous.get("pid", -1))
                if (
                    fcntl is None
                    and local
                    and pid != os.getpid()
                    and _process_alive(pid, previous.get("process_start"))
                ):
                    os.close(fd)
                    raise self._refuse(previous)
                if pid != os.getpid() or not local:
                    warnings.warn(
                        f"'{self.directory}' was locked by {_describe(previous)}, which no longer runs: "
                        "taking over its lock",
                        RecoveryWarning,
                        stacklevel=2,
                    )
            try:
                os.ftruncate(fd, 0)
                os.write(fd, json.dumps(self._owner_record()).encode("utf-8"))
                os.fsync(fd)
            except OSError as exc:  # a full disk: no lock file is left behind, empty or not
                with contextlib.suppress(OSError):
                    os.unlink(self.path)
                os.close(fd)
                if self._created:
                    with contextlib.suppress(OSError):
                        self.directory.rmdir()
                if is_disk_full(exc):
                    raise disk_full_error(self.path, "nothing was written (no lock file is left)") from None
                raise EdofprojError(f"cannot lock '{self.directory}': {exc.strerror or exc}") from None
            self._fd = fd
            return self
        raise EdofprojError(f"cannot lock '{self.directory}': its lock file keeps changing")

    def release(self) -> None:
        """Remove the lock file and release the lock (idempotent); a directory the lock created
        and nothing was written to is removed too."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        with contextlib.suppress(OSError):
            if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                os.unlink(self.path)
        os.close(fd)  # closing releases the flock
        if self._created:
            with contextlib.suppress(OSError):
                self.directory.rmdir()  # only when empty

    def __enter__(self) -> "DirectoryLock":
        return self.acquire()

    def __exit__(self, *exc_info) -> None:
        self.release()


@contextlib.contextmanager
def directory_lock(
    directory: str | os.PathLike, what: str = "edofproj", option: str = "", beside: bool = False
) -> Iterator[DirectoryLock]:
    """``with directory_lock(path, "edofproj train", "--out"):`` hold ``path``'s write lock
    (:class:`DirectoryLock`; ``beside``: the lock file sits beside the directory)."""
    lock = DirectoryLock(directory, what, option, beside)
    with lock:
        yield lock


@contextlib.contextmanager
def sole_file_writer(path: str | os.PathLike, what: str = "edofproj", option: str = "--out") -> Iterator[DirectoryLock]:
    """``with sole_file_writer(out, "edofproj export"):`` write the file ``path`` (atomically,
    :func:`edofproj.fileio.atomic_path`) as its one writer: hold its lock (the lock file
    ``.<name>.edofproj.lock`` beside it; a second live writer is refused with one line naming the
    first) and, under it, remove the temporary files ``.<name>.tmp-*`` that killed writers of the same
    file left (no live writer can own them then: :func:`edofproj.fileio.remove_stale_temp_files`
    with ``target``), with a :class:`~edofproj.errors.RecoveryWarning`."""
    from .fileio import remove_stale_temp_files

    target = Path(path)
    if target.is_dir():
        raise EdofprojError(f"{option} '{target}' is a directory: give a file name")
    with DirectoryLock(target, what, option, of_file=True) as lock:
        stale = remove_stale_temp_files(target.parent, target=target.name)
        if stale:
            warnings.warn(
                f"removed {len(stale)} unfinished file(s) of an interrupted write of '{target}' "
                f"({', '.join(p.name for p in stale)})",
                RecoveryWarning,
                stacklevel=3,
            )
        yield lock
