"""Measuring a coloured, textured surface: per-pixel reflectance and ambient from two extra captures.

A calibration (:mod:`.calibration`) made on a white screen (or a white board held where the
object will stand) fixes the map camera -> projector pixels and the colour space: projector
output light, ``o = M^-1 (c - c_black)``, in which a white surface under the full primary shows 1.
With the object in place, the projector then shows two more fields (the manifest's ``black`` and
``white`` patterns, each captured ``n >= 1`` times and averaged):

    a(x) = M^-1 c_black(q(x))                                   ambient: what the surface shows
                                                                  with the projector black
    s(x) = M^-1 (c_white(q(x)) - c_black(q(x)))                  reflectance: the gain of the
                                                                  full field over black

(``q(x)`` the camera point that sees projector pixel ``x``), so that what the camera sees of any
projector input ``L`` (linear output, :meth:`~.calibration.ProCamsCalibration.to_projector_input`
inverts the response) is ``M^-1 c = s ⊙ (PSF ⊛ L) + a`` -- the model of
:mod:`edofproj.imaging.surfaces`. ``a`` is absolute (not relative to the calibration's black
image): it holds the surface's ambient light, the projector's black level reflected by the
surface and the camera's own offset.

Where exact: the full field's projection is uniform (1) away from the image border and from depth
edges (there the blur of the field's edge, or of a neighbouring surface, enters): ``s`` there is
the reflectance; near them it is the gain of the full field, which is what compensation needs.

Values: ``s`` is clipped to ``[0, 1]`` and ``a`` to ``>= 0`` (camera noise makes a few pixels
stray); when more than :data:`BRIGHTER_THAN_WHITE_FRACTION` of the pixels reflect more than
:data:`BRIGHTER_THAN_WHITE` of the calibration's white, a warning says that the colour
calibration was not made on a white surface (its white is then the reference, not 1).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import EdofprojError
from ..imaging.surfaces import Surface
from .calibration import ProCamsCalibration
from .capture_io import read_captures
from .patterns import PatternManifest

#: A measured reflectance above this (of the calibration's white) counts as brighter than white.
BRIGHTER_THAN_WHITE = 1.05
#: More than this fraction of pixels brighter than white: warn (colour not calibrated on white).
BRIGHTER_THAN_WHITE_FRACTION = 0.01


@dataclass
class SurfaceMeasurement:
    """A surface as measured (module docstring): ``reflectance`` in ``[0, 1]`` and ``ambient >= 0``,
    each ``(H, W, 3)`` float32 in projector pixels, in projector output units."""

    reflectance: np.ndarray
    ambient: np.ndarray

    def as_surface(self) -> Surface:
        """The :class:`~edofproj.imaging.surfaces.Surface` that the forward model and networks take."""
        return Surface.from_arrays(self.reflectance, self.ambient[None].transpose(0, 3, 1, 2))


def _mean_capture(captures: Sequence[np.ndarray] | np.ndarray, what: str) -> np.ndarray:
    frames = [captures] if isinstance(captures, np.ndarray) else list(captures)
    if not frames:
        raise EdofprojError(f"no {what} capture: the surface needs at least one of each (black, white)")
    shapes = {tuple(f.shape) for f in frames}
    if len(shapes) != 1:
        raise EdofprojError(f"the {what} captures differ in size: {sorted(shapes)}")
    return np.mean([np.asarray(f, dtype=np.float64) for f in frames], axis=0)


def measure_surface(
    calibration: ProCamsCalibration,
    black_captures: Sequence[np.ndarray] | np.ndarray,
    white_captures: Sequence[np.ndarray] | np.ndarray,
) -> SurfaceMeasurement:
    """Reflectance and ambient per projector pixel from captures ``(Hc, Wc, 3)`` of the black and the
    full-white field with the object in place (each a list of repeated frames, averaged)."""
    black = calibration.camera_map.warp(_mean_capture(black_captures, "black").astype(np.float32))
    white = calibration.camera_map.warp(_mean_capture(white_captures, "white").astype(np.float32))
    ambient = calibration.color.camera_to_output(black, np.zeros(3))
    reflectance = calibration.color.camera_to_output(white, black)
    bright = float(np.mean(reflectance > BRIGHTER_THAN_WHITE))
    if bright > BRIGHTER_THAN_WHITE_FRACTION:
        warnings.warn(
            f"the surface reflects more than the calibration's white at {100 * bright:.1f} % of its pixels: "
            "calibrate colour on a white board, then capture the object (its reflectance is clipped to 1)",
            stacklevel=2,
        )
    return SurfaceMeasurement(
        reflectance=np.clip(reflectance, 0.0, 1.0).astype(np.float32),
        ambient=np.clip(ambient, 0.0, None).astype(np.float32),
    )


def surface_capture_files(manifest: PatternManifest) -> tuple[str, list[str]]:
    """The pattern files of the surface captures: the manifest's black field and its white one(s)."""
    white = [e.file for e in manifest.with_role("white")]
    if not white:
        raise EdofprojError("the pattern manifest has no white field (role 'white'): the surface needs one")
    return manifest.one("black").file, white


def measure_surface_folders(
    calibration: ProCamsCalibration, pattern_dir: str | Path, capture_dir: str | Path
) -> SurfaceMeasurement:
    """:func:`measure_surface` on the black and white captures of ``capture_dir`` (named as the
    patterns of ``pattern_dir``), taken with the object in place."""
    manifest = PatternManifest.load(pattern_dir)
    calibration.check_projector_hw((manifest.height, manifest.width), "the pattern set")
    black, white = surface_capture_files(manifest)
    captures = read_captures(capture_dir, [black, *white])
    return measure_surface(calibration, captures[black], [captures[name] for name in white])
