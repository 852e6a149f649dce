"""A capture session: show every pattern of a manifest and capture it, resumably.

The capture folder holds one capture per pattern under the pattern's file name (PNG, 8-bit,
or 16-bit for a mean of several frames; each written atomically: temp file, then rename) and ``captures.json``::

    {"source": "edofproj procams capture", "patterns": ".../manifest.json",
     "projector_hw": [H, W], "camera_hw": [Hc, Wc], "depth_mm": Z,
     "display": {...}, "camera": {...}, "cameras": {"SPEC": n}, "settle_s": s, "average": N,
     "captured": n, "total": N_patterns, "complete": true|false,
     "patterns_sha256": "..."}

An interrupted session (Ctrl-C, a camera that stops answering) keeps every capture already
written; running it again skips them and continues. A folder is resumed only with the same
pattern manifest, depth and number of frames averaged, and every capture must have the camera
size of the first. The session is tied to the *content* of its patterns: ``patterns_sha256``
(:meth:`PatternManifest.content_hash`, the manifest and every pattern file) must match on
resume, so patterns regenerated in place (another seed or size) are refused. It is tied to its
camera as well: a session holding captures is resumed only with the same ``--camera`` spec
(``cameras`` records the captures each camera took; :func:`~.capture_io.read_captures`, which
``calibrate`` and ``estimate-psf`` read through, refuses a folder whose record names several). Each capture
already in the folder is read back before it counts: one that does not decode or has another
size than the session's camera is removed and captured again (with a ``RecoveryWarning``).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import EdofprojError, RecoveryWarning
from ..fileio import remove_stale_temp_files, write_text_atomic
from ..imaging.image_io import write_image
from ..locking import directory_lock
from .capture_io import CAPTURE_INFO_JSON, read_rgb, saturated_fraction, write_rgb_png
from .devices import Camera, Display, GrabSettings, grab_frame
from .devices.base import SATURATION_WARN_FRACTION
from .patterns import MANIFEST_NAME, PatternManifest, read_pattern

CAPTURE_SOURCE = "edofproj procams capture"


@dataclass
class CaptureResult:
    captured: int
    skipped: int
    total: int
    camera_hw: tuple[int, int] | None


def _load_info(out: Path) -> dict | None:
    path = out / CAPTURE_INFO_JSON
    if not path.is_file():
        return None
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:  # UnicodeDecodeError is one
        raise EdofprojError(f"'{path}' is not valid JSON: {exc}") from None
    if not isinstance(info, dict):
        raise EdofprojError(f"'{path}' is not a capture session's record (a JSON object): use another --out")
    return info


def _check_resume(
    out: Path, info: dict | None, manifest_path: Path, depth_mm: float | None, patterns_sha256: str
) -> dict | None:
    """The existing session's ``captures.json`` if ``out`` can be resumed, else raise; None if new."""
    if info is None:
        if out.is_dir() and any(out.iterdir()):
            raise EdofprojError(
                f"'{out}' is not empty and holds no {CAPTURE_INFO_JSON}: not a capture session to resume"
            )
        return None
    if info.get("source") != CAPTURE_SOURCE:
        raise EdofprojError(f"'{out}' was not written by 'edofproj procams capture' (source: {info.get('source')})")
    if info.get("patterns") != str(manifest_path):
        raise EdofprojError(f"'{out}' is a session of other patterns ({info.get('patterns')}): use another --out")
    if "patterns_sha256" not in info:
        raise EdofprojError(
            f"'{out}' does not record its patterns' content (patterns_sha256; an earlier edofproj wrote it): "
            "capture into a new --out"
        )
    if info.get("patterns_sha256") != patterns_sha256:
        raise EdofprojError(
            f"the patterns of '{out}' have changed since it was captured (their content differs from "
            f"{CAPTURE_INFO_JSON}'s patterns_sha256): capture into a new --out"
        )
    if info.get("depth_mm") != depth_mm:
        raise EdofprojError(
            f"'{out}' was captured at --depth-mm {info.get('depth_mm')}, not {depth_mm}: resume with the same depth"
        )
    return info


def _session_cameras(previous: dict | None) -> list[str]:
    """The camera specs a session's record names (``cameras``, and ``camera`` of older records)."""
    if previous is None:
        return []
    recorded = previous.get("camera")
    specs = {recorded["spec"]} if isinstance(recorded, dict) and isinstance(recorded.get("spec"), str) else set()
    cameras = previous.get("cameras")
    if isinstance(cameras, dict):
        specs |= {str(spec) for spec in cameras}
    return sorted(specs)


def _check_camera(out: Path, previous: dict | None, camera: Camera, done: int, todo: int) -> bool:
    """Whether ``camera`` is the session's: a session that holds captures (``done``) is resumed with
    another camera only when nothing is left to capture (``todo``: then it takes nothing), else refused."""
    specs = _session_cameras(previous)
    if not done or not specs or specs == [camera.spec]:
        return True
    if todo:
        raise EdofprojError(
            f"'{out}' was captured with --camera '{', '.join(specs)}', not '{camera.spec}': a session is tied to its "
            "camera; resume with the same --camera, or capture into a new --out"
        )
    return False


def _stored_camera_hw(previous: dict | None, out: Path) -> tuple[int, int] | None:
    """The camera size a resumed session recorded (None for a new one), checked."""
    stored = previous.get("camera_hw") if previous else None
    if stored is None:
        return None
    if not (
        isinstance(stored, list)
        and len(stored) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in stored)
    ):
        raise EdofprojError(f"'{out / CAPTURE_INFO_JSON}' gives camera_hw {stored!r}, not [height, width]")
    return stored[0], stored[1]


def _verify_existing_captures(out: Path, files: list[str], camera_hw: tuple[int, int] | None) -> tuple[int, int] | None:
    """Read back every capture of ``files`` already in ``out``; remove those that do not decode or
    differ in size from ``camera_hw`` (or from the first readable one), with one ``RecoveryWarning``.
    Returns the camera size (None when no capture is there)."""
    damaged = []
    for name in files:
        path = out / name
        if not path.is_file():
            continue
        try:
            shape = read_rgb(path, what="capture").shape[:2]
        except EdofprojError:
            damaged.append(name)
            continue
        if camera_hw is None:
            camera_hw = (int(shape[0]), int(shape[1]))
        elif tuple(shape) != tuple(camera_hw):
            damaged.append(name)
    for name in damaged:
        (out / name).unlink()
    if damaged:
        warnings.warn(
            f"{len(damaged)} capture(s) in '{out}' did not decode or had another size than the camera's "
            f"(first: '{damaged[0]}'): removed, they are captured again",
            RecoveryWarning,
            stacklevel=3,
        )
    return camera_hw


def capture_patterns(
    pattern_dir: str | Path,
    out_dir: str | Path,
    display: Display,
    camera: Camera,
    grab: GrabSettings = GrabSettings(),
    depth_mm: float | None = None,
    log: Callable[[str], None] | None = None,
    stop_after: int | None = None,
) -> CaptureResult:
    """Show and capture every pattern of ``pattern_dir`` not yet in ``out_dir`` (module docstring).

    ``stop_after``: capture at most this many new patterns (then return, as an interruption would).
    """
    manifest = PatternManifest.load(pattern_dir)
    manifest_path = (Path(pattern_dir) / MANIFEST_NAME).resolve()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise EdofprojError(f"'{out}' exists and is not a folder")
    patterns_sha256 = manifest.content_hash(pattern_dir)
    previous = _check_resume(out, _load_info(out), manifest_path, depth_mm, patterns_sha256)
    if previous is not None and previous.get("average", grab.average) != grab.average:
        raise EdofprojError(
            f"'{out}' was captured with --average {previous.get('average')}, not {grab.average}: resume with the same"
        )
    out.mkdir(parents=True, exist_ok=True)
    # one capture session per folder; temporary files of an interrupted write are removed under the lock
    with directory_lock(out, "edofproj procams capture", "--out"):
        remove_stale_temp_files(out)
        camera_hw = _stored_camera_hw(previous, out)
        info = {
            "source": CAPTURE_SOURCE,
            "patterns": str(manifest_path),
            "projector_hw": [manifest.height, manifest.width],
            "camera_hw": list(camera_hw) if camera_hw else None,
            "depth_mm": depth_mm,
            "display": display.settings(),
            "camera": camera.settings(),
            "settle_s": grab.settle_s,
            "average": grab.average,
            "total": len(manifest.entries),
            "patterns_sha256": patterns_sha256,
        }
        camera_hw = _verify_existing_captures(out, [e.file for e in manifest.entries], camera_hw)
        done = [e for e in manifest.entries if (out / e.file).is_file()]
        todo = [e for e in manifest.entries if not (out / e.file).is_file()]
        cameras = {camera.spec: len(done)}
        if previous is not None and not _check_camera(out, previous, camera, len(done), len(todo)):
            info["camera"] = previous.get("camera")  # a complete session: the other camera took nothing
            cameras = previous["cameras"] if isinstance(previous.get("cameras"), dict) else {}

        def write_info(captured: int) -> None:
            info.update(camera_hw=list(camera_hw) if camera_hw else None, captured=captured)
            if cameras.get(camera.spec) is not None:  # the session's camera (never another one's count)
                cameras[camera.spec] = captured
            info["cameras"] = {spec: n for spec, n in cameras.items() if n}
            info["complete"] = captured == len(manifest.entries)
            write_text_atomic(out / CAPTURE_INFO_JSON, json.dumps(info, indent=1) + "\n")

        write_info(len(done))
        if done and log is not None:
            log(f"resuming: {len(done)} of {len(manifest.entries)} patterns already captured in {out}")
        captured = 0
        saturated: dict[str, float] = {}
        try:
            for entry in todo[:stop_after] if stop_after is not None else todo:
                display.show(read_pattern(pattern_dir, entry, manifest))
                frame = grab_frame(camera, grab, warn=False)
                fraction = saturated_fraction(frame)
                if fraction > SATURATION_WARN_FRACTION:
                    saturated[entry.file] = fraction
                if camera_hw is None:
                    camera_hw = frame.shape[:2]
                elif frame.shape[:2] != tuple(camera_hw):
                    raise EdofprojError(
                        f"capture of '{entry.file}' is {frame.shape[0]}x{frame.shape[1]} pixels, the session's camera "
                        f"{camera_hw[0]}x{camera_hw[1]} (height x width): did the camera's resolution change?"
                    )
                if grab.average > 1:  # a mean of frames has more than 8 bits
                    write_image(out / entry.file, np.ascontiguousarray(frame.transpose(2, 0, 1)), bits=16)
                else:
                    write_rgb_png(out / entry.file, frame)
                captured += 1
                if log is not None and (len(done) + captured) % 25 == 0:
                    log(f"  {len(done) + captured}/{len(manifest.entries)} captured")
        finally:
            write_info(len(done) + captured)
            if saturated:
                worst = max(saturated, key=saturated.__getitem__)
                warnings.warn(
                    f"{len(saturated)} of {captured} captures have saturated pixels (worst '{worst}': "
                    f"{100 * saturated[worst]:.1f} % of its pixels); saturated light is not measured -- lower the exposure",
                    stacklevel=2,
                )
        return CaptureResult(captured=captured, skipped=len(done), total=len(manifest.entries), camera_hw=camera_hw)
