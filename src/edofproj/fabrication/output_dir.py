"""All-or-nothing output directories: build every file in a staging directory, then rename it into place.

A failed export therefore leaves no partial GDSII (nor any other file) behind: the staging
directory is removed and the previous output, if any, is untouched. One export per output at a
time (a lock beside it, :mod:`edofproj.locking`); the staging folders of an export killed with
``kill -9`` are removed by the next export to the same place.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import EdofprojError
from ..fileio import remove_stale_folders
from ..locking import directory_lock


def check_replaceable(out_dir: Path, marker: str) -> None:
    """``out_dir`` must be missing, empty, or a previous output (holding ``marker``)."""
    if not out_dir.exists():
        return
    if not out_dir.is_dir():
        raise EdofprojError(f"--out '{out_dir}' exists and is not a directory")
    if any(out_dir.iterdir()) and not (out_dir / marker).is_file():
        raise EdofprojError(
            f"--out '{out_dir}' is a non-empty directory without {marker}: choose a new or empty directory"
        )


@contextlib.contextmanager
def staged_directory(out_dir: str | os.PathLike, marker: str) -> Iterator[Path]:
    """Yield an empty staging directory beside ``out_dir``; on success it replaces ``out_dir``.

    ``marker`` is a file every complete output contains; an existing non-empty ``out_dir``
    without it is refused before any work starts (we never delete foreign files).
    """
    target = Path(out_dir)
    check_replaceable(target, marker)
    target.parent.mkdir(parents=True, exist_ok=True)
    with directory_lock(target, "edofproj export-doe", "--out", beside=True):
        remove_stale_staging(target)
        with _staged(target, marker) as staging:
            yield staging


def remove_stale_staging(target: Path) -> list[Path]:
    """Delete the ``.<name>.XXXXXXXX.staging`` and ``.old`` folders that a killed export left beside
    ``target`` (call while holding ``target``'s lock: no live export owns them)."""
    pattern = re.compile(rf"^\.{re.escape(target.name)}\.[A-Za-z0-9_]{{8}}\.(?:staging|old)$")
    return remove_stale_folders(
        (p for p in target.parent.iterdir() if pattern.match(p.name)),
        f"unfinished folder(s) of an interrupted export beside '{target}'",
        stacklevel=4,
    )


@contextlib.contextmanager
def _staged(target: Path, marker: str) -> Iterator[Path]:
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".staging", dir=target.parent))
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)  # mkdtemp makes it private; the output should not be
    try:
        yield staging
        if not (staging / marker).is_file():
            raise RuntimeError(f"staged output lacks {marker}")
        check_replaceable(target, marker)
        backup = None
        if target.exists():
            backup = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.rmdir(backup)
            os.replace(target, backup)
        try:
            os.replace(staging, target)
        except BaseException:
            if backup is not None:
                os.replace(backup, target)
            raise
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
