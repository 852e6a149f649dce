"""An evaluation's files written as a set: all of them in a staging folder first, then swapped in.

``evaluate`` writes several files that belong together (``metrics.csv``, ``tilted_metrics.csv``,
``figures/eval_*.png``, ``summary.md``, ``report.md``, ``report.html``) into a folder that may
already hold an earlier evaluation's (a run directory, or ``--out`` again). Written one by one in
place, a process killed half-way would leave new tables beside an old report. Instead every file
is written into ``<out>/.evaluate-staging-XXXXXXXX/`` with the final layout; only when the whole
set is there is each file renamed onto its place (same filesystem: ``os.replace``, atomic per
file, all renames together take milliseconds). A staging folder that a killed evaluation left is
removed by the next one (which holds the folder's lock, :mod:`edofproj.locking`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import EdofprojError
from ..fileio import remove_stale_folders

STAGING_PREFIX = ".evaluate-staging-"


def remove_stale_staging(out_dir: Path) -> list[Path]:
    """Delete the staging folders of interrupted evaluations in ``out_dir`` (call under its lock)."""
    return remove_stale_folders(
        out_dir.glob(STAGING_PREFIX + "*"),
        f"unfinished evaluation(s) of an interrupted evaluate from '{out_dir}'",
        stacklevel=3,
    )


@contextlib.contextmanager
def staged_output_set(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty staging folder inside ``out_dir``; on success move every file written there
    onto the same relative path in ``out_dir`` (module docstring); on failure remove it, leaving
    ``out_dir`` as it was."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(out)
        stage = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=out))
    except OSError as exc:
        raise EdofprojError(f"cannot write into '{out}': {exc.strerror or exc}") from None
    try:
        yield stage
        files = sorted(p for p in stage.rglob("*") if p.is_file())
        for path in files:
            target = out / path.relative_to(stage)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, target)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def moved_path(path: Path, stage: Path, out_dir: Path) -> Path:
    """Where a file written at ``path`` inside ``stage`` lies after the swap."""
    return Path(out_dir) / Path(path).relative_to(stage)
