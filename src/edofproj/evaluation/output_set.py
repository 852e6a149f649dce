"""An evaluation's files written as a set: all of them in a staging folder first, then swapped in.

``evaluate`` writes several files that belong together (``metrics.csv``, ``tilted_metrics.csv``,
``figures/eval_*.png``, ``summary.md``, ``report.md``, ``report.html``) into a folder that may
already hold an earlier evaluation's (a run directory, or ``--out`` again). Written one by one in
place, a process killed half-way would leave new tables beside an old report. Instead every file
is written into ``<out>/.evaluate-staging-XXXXXXXX/`` with the final layout; only when the whole
set is there is each file renamed onto its place (same filesystem: ``os.replace``, atomic per
file, all renames together take milliseconds). A staging folder that a killed evaluation left is
removed by the next one (which holds the folder's lock, :mod:`edofproj.locking`).

The new set replaces the previous one *as a whole*: every file of an earlier evaluation
(:data:`EVALUATION_FILES`, the files of any kind of evaluation: flat screens, scenes, surfaces)
that the new set does not hold is removed, so no table of an earlier run is left beside the new
report. Other files (a run directory's configuration and checkpoints) are never touched. A full
disk ends in one line that says the previous results are kept (they are: nothing was swapped).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from ..errors import DiskFullError, EdofprojError
from ..fileio import disk_full_error, is_disk_full, remove_stale_folders

STAGING_PREFIX = ".evaluate-staging-"

#: Every file an evaluation writes into its output folder, as glob patterns relative to it (the
#: names of :mod:`.pipeline`, :mod:`.scenes`, :mod:`.surfaces` and of their reports):
#: the output set that a new evaluation replaces as a whole.
EVALUATION_FILES = (
    "metrics.csv",
    "tilted_metrics.csv",
    "scene_metrics.csv",
    "surface_metrics.csv",
    "summary.md",
    "scene_summary.md",
    "surface_summary.md",
    "report.md",
    "report.html",
    "figures/eval_*.png",
)


def remove_stale_staging(out_dir: Path) -> list[Path]:
    """Delete the staging folders of interrupted evaluations in ``out_dir`` (call under its lock)."""
    return remove_stale_folders(
        out_dir.glob(STAGING_PREFIX + "*"),
        f"unfinished evaluation(s) of an interrupted evaluate from '{out_dir}'",
        stacklevel=3,
    )


@contextlib.contextmanager
def staged_output_set(out_dir: str | os.PathLike, replaces: Iterable[str] = EVALUATION_FILES) -> Iterator[Path]:
    """Yield an empty staging folder inside ``out_dir``; on success move every file written there
    onto the same relative path in ``out_dir`` and remove the files of ``out_dir`` matching
    ``replaces`` (glob patterns) that the new set lacks (module docstring); on failure remove the
    staging folder, leaving ``out_dir`` as it was."""
    out = Path(out_dir)
    kept = f"the previous results in '{out}' are kept"
    try:
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(out)
        stage = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=out))
    except OSError as exc:
        if is_disk_full(exc):
            raise disk_full_error(out, kept) from None
        raise EdofprojError(f"cannot write into '{out}': {exc.strerror or exc}") from None
    try:
        try:
            yield stage
        except BaseException as exc:
            if isinstance(exc, DiskFullError) or is_disk_full(exc):
                raise disk_full_error(out, kept) from None
            raise
        files = sorted(p for p in stage.rglob("*") if p.is_file())
        new = {path.relative_to(stage) for path in files}
        previous = {p for pattern in replaces for p in out.glob(pattern) if p.is_file() and not p.is_symlink()}
        for path in files:
            target = out / path.relative_to(stage)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, target)
        for path in sorted(previous):
            if path.relative_to(out) not in new:
                path.unlink(missing_ok=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def moved_path(path: Path, stage: Path, out_dir: Path) -> Path:
    """Where a file written at ``path`` inside ``stage`` lies after the swap."""
    return Path(out_dir) / Path(path).relative_to(stage)
