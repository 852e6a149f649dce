"""Files of a projector-camera session: RGB images, capture folders, and folders written atomically.

Images are ``(H, W, 3)`` float32 RGB arrays in ``[0, 1]`` here (NumPy, the layout OpenCV works
in), read and written with :mod:`edofproj.imaging.image_io`: 8- and 16-bit files are read,
8-bit PNGs written. A capture folder holds one
capture per pattern under the pattern's file name (see :mod:`.patterns`); every capture of
one session has the camera's size.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..errors import DiskFullError, EdofprojError, RecoveryWarning
from ..fileio import disk_full_error, is_disk_full, kept_phrase, user_mode
from ..imaging.image_io import read_image_array, to_unit_float, write_image
from ..locking import directory_lock

CAPTURE_INFO_JSON = "captures.json"
"""The record of how a capture folder was made (``procams capture``, ``procams simulate``)."""

SATURATION_LEVEL = 1.0 - 0.5 / 255.0
"""A value counts as saturated within half an 8-bit step of the sensor's top."""


def read_rgb(path: str | Path, what: str = "image") -> np.ndarray:
    """An 8- or 16-bit image file as ``(H, W, 3)`` float32 RGB in ``[0, 1]``
    (:func:`edofproj.imaging.image_io.read_image_array`, kept in OpenCV's ``H, W, C`` layout)."""
    return to_unit_float(read_rgb_counts(path, what))


def read_rgb_counts(path: str | Path, what: str = "image") -> np.ndarray:
    """The same file's integer counts, ``(H, W, 3)`` ``uint8`` or ``uint16`` RGB."""
    path = Path(path)
    if not path.is_file():
        raise EdofprojError(f"{what} '{path}' does not exist")
    return read_image_array(path)


def write_rgb_png(path: str | Path, image: np.ndarray) -> None:
    """Write an ``(H, W, 3)`` image in ``[0, 1]`` as an 8-bit RGB PNG, atomically."""
    write_image(path, np.ascontiguousarray(np.asarray(image, dtype=np.float32).transpose(2, 0, 1)), bits=8)


def read_captures(
    folder: str | Path, files: Iterable[str], expected_hw: tuple[int, int] | None = None
) -> dict[str, np.ndarray]:
    """The captures ``{file: (H, W, 3)}`` of ``files`` from ``folder``.

    Raises one line naming the missing captures, or the first capture whose size differs from
    ``expected_hw`` (or, without it, from the first capture), or when the folder's record says its
    captures come from several cameras (:func:`check_one_camera`).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise EdofprojError(f"capture folder '{folder}' does not exist")
    check_one_camera(folder)
    files = list(files)
    missing = [f for f in files if not (folder / f).is_file()]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise EdofprojError(f"capture folder '{folder}' lacks {len(missing)} of {len(files)} captures: {shown}")
    captures = {}
    for name in files:
        image = read_rgb(folder / name, what="capture")
        if expected_hw is None:
            expected_hw = image.shape[:2]
        if image.shape[:2] != tuple(expected_hw):
            raise EdofprojError(
                f"capture '{name}' is {image.shape[0]}x{image.shape[1]} pixels, expected "
                f"{expected_hw[0]}x{expected_hw[1]} (height x width, the camera's size)"
            )
        captures[name] = image
    return captures


def recorded_cameras(folder: str | Path) -> list[str]:
    """The cameras whose captures a capture folder holds, as its ``captures.json`` records them
    (``cameras``: ``{spec: captures}``, written by ``procams capture``); empty without a record."""
    path = Path(folder) / CAPTURE_INFO_JSON
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    cameras = info.get("cameras") if isinstance(info, dict) else None
    return [str(spec) for spec in cameras] if isinstance(cameras, dict) else []


def check_one_camera(folder: str | Path) -> None:
    """Refuse a capture folder whose captures were taken by more than one camera (its record names
    several): a calibration or PSF needs one camera's geometry and response."""
    cameras = recorded_cameras(folder)
    if len(cameras) > 1:
        raise EdofprojError(
            f"capture folder '{folder}' mixes the captures of {len(cameras)} cameras ({', '.join(cameras)}; "
            f"{CAPTURE_INFO_JSON}): capture every pattern with one camera"
        )


def saturated_fraction(image: np.ndarray) -> float:
    """Fraction of pixels with at least one channel at the sensor's top value."""
    return float(np.mean(np.any(np.asarray(image) >= SATURATION_LEVEL, axis=-1)))


@contextlib.contextmanager
def atomic_folder(path: str | Path, overwrite: bool = False, what: str = "edofproj procams") -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``path``; on success it becomes ``path``.

    An existing non-empty ``path`` is refused (before any work) unless ``overwrite``; then it
    is replaced only after the new folder is complete. On failure nothing at ``path`` changes.
    One writer at a time: the folder is locked (:mod:`edofproj.locking`, the lock file beside
    it, naming the writer ``what``, e.g. ``"edofproj compensate"``) while it is written, and
    temporary folders that a killed writer left are removed first. The folder gets the user's
    usual permissions (``0o777`` less the umask), and a full disk ends in one line naming the
    disk and saying that the previous folder is kept (:func:`edofproj.fileio.disk_full_error`).
    The caller checks that ``path`` is none of its inputs (:mod:`edofproj.outputs`).
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise EdofprojError(f"'{target}' exists and is not a folder")
    with directory_lock(target, what, beside=True):
        if target.is_dir() and any(target.iterdir()) and not overwrite:
            raise EdofprojError(f"folder '{target}' exists and is not empty (use --overwrite to replace it)")
        _remove_stale_temp_folders(target)
        kept = kept_phrase(target)
        try:
            tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
        except OSError as exc:
            if is_disk_full(exc):
                raise disk_full_error(target, kept) from None
            raise
        try:
            tmp.chmod(user_mode(0o777))  # mkdtemp makes it private (0700); the output should not be
            yield tmp
            if target.is_dir():
                old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
                os.replace(target, old / "previous")
                os.replace(tmp, target)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, target)
        except BaseException as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(exc, DiskFullError) or is_disk_full(exc):
                raise disk_full_error(target, kept) from None
            raise


def _remove_stale_temp_folders(target: Path) -> None:
    """The ``.<name>.XXXXXXXX`` and ``.<name>.old.XXXXXXXX`` folders of :func:`atomic_folder` beside
    ``target`` (only called while holding ``target``'s lock: no live writer owns them)."""
    pattern = re.compile(rf"^\.{re.escape(target.name)}\.(?:old\.)?[a-z0-9_]{{8}}$")
    stale = [p for p in target.parent.iterdir() if p.is_dir() and pattern.match(p.name)]
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    if stale:
        warnings.warn(
            f"removed {len(stale)} unfinished folder(s) of an interrupted write beside '{target}'",
            RecoveryWarning,
            stacklevel=3,
        )


__all__ = [
    "read_rgb",
    "read_rgb_counts",
    "write_rgb_png",
    "read_captures",
    "saturated_fraction",
    "recorded_cameras",
    "check_one_camera",
    "CAPTURE_INFO_JSON",
    "atomic_folder",
    "SATURATION_LEVEL",
]
