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

Refused in one line: a white field darker than the black one at most pixels (the two captures
swapped), and a surface that cannot show an image (a black object, the projector off:
:func:`edofproj.compensation.achievable.require_visible`).

**Registration.** The surface is read through the calibration's camera map, so the camera must
not move between the calibration's captures and the surface's. :func:`camera_shift_px` measures
the move: the cross-correlation (:func:`skimage.registration.phase_cross_correlation` without
spectral whitening, upsampled 20 times) of the full field less black, ``c_white - c_black``
(camera grey levels), of the two sessions; the field's bright frame dominates it, not the
object's texture (whitened phase correlation follows the texture and misses). On the virtual
ProCams (128×96 projector, 2.75 camera px per projector px, ``checker`` and ``leaves``) it reads
at most 0.10 camera px for a camera that did not move and ``d ± 0.1`` for a move of ``d = 0.25 ... 4``
camera px; the measured reflectance is off by more than 0.1 at 0 % of the pixels for a move of
0.5 camera px (0.18 projector px), 1.6-2.1 % for 1 camera px (0.36 projector px), 11-25 % for 2.
A move above :data:`MAX_CAMERA_SHIFT_PX` projector pixels is refused.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from skimage.registration import phase_cross_correlation

from ..compensation.achievable import MIN_GAIN, require_visible
from ..errors import EdofprojError
from ..imaging.surfaces import Surface
from .calibration import ProCamsCalibration
from .capture_io import read_captures
from .patterns import PatternManifest

#: A measured reflectance above this (of the calibration's white) counts as brighter than white.
BRIGHTER_THAN_WHITE = 1.05
#: More than this fraction of pixels brighter than white: warn (colour not calibrated on white).
BRIGHTER_THAN_WHITE_FRACTION = 0.01
#: Largest camera move between the calibration's captures and the surface's, in projector pixels
#: (module docstring: above the 0.04 px a still camera reads, below the 0.36 px that errs).
MAX_CAMERA_SHIFT_PX = 0.2
#: Upsampling of the cross-correlation peak: camera moves are read to 1/20 camera pixel.
REGISTRATION_UPSAMPLING = 20
#: What a surface refused as unable to show an image may come from.
SURFACE_HINT = (
    " -- were the white and black fields swapped, the projector off, or is the object black? capture them "
    "again (procams calibrate --surface-captures)"
)


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
    darker = float(np.mean(reflectance.mean(axis=2) < -MIN_GAIN))  # beyond noise: a black object reads ~0
    if darker > 0.5:
        raise EdofprojError(
            f"the white field is darker than the black one at {100 * darker:.0f} % of the surface's pixels: were the "
            "white and black captures swapped? capture them again (procams calibrate --surface-captures)"
        )
    rho_chw = torch.from_numpy(np.clip(reflectance, 0.0, 1.0).transpose(2, 0, 1).astype(np.float32))[None]
    ambient_chw = torch.from_numpy(np.clip(ambient, 0.0, None).transpose(2, 0, 1).astype(np.float32))[None]
    require_visible(rho_chw, ambient_chw, "the surface measured", SURFACE_HINT)
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


def _field_less_black(black: np.ndarray, whites: Sequence[np.ndarray]) -> np.ndarray:
    """The mean full field less black, in camera grey levels ``(Hc, Wc)``."""
    return (_mean_capture(whites, "white") - _mean_capture(black, "black")).mean(axis=2)


def camera_shift_px(
    reference: tuple[np.ndarray, Sequence[np.ndarray]], moved: tuple[np.ndarray, Sequence[np.ndarray]]
) -> np.ndarray:
    """The camera's move ``(dy, dx)`` in camera pixels between two sessions, each given as its
    ``(black capture, white captures)`` ``(Hc, Wc, 3)`` (module docstring: the cross-correlation of
    ``c_white - c_black``, to 1/:data:`REGISTRATION_UPSAMPLING` px)."""
    first, second = _field_less_black(*reference), _field_less_black(*moved)
    if first.shape != second.shape:
        raise EdofprojError(
            f"the surface captures are {second.shape[0]}x{second.shape[1]} px (height x width) but the "
            f"calibration's are {first.shape[0]}x{first.shape[1]}: one camera takes both"
        )
    shift, _, _ = phase_cross_correlation(first, second, upsample_factor=REGISTRATION_UPSAMPLING, normalization=None)
    return np.asarray(shift, dtype=float)


def measure_surface_folders(
    calibration: ProCamsCalibration,
    pattern_dir: str | Path,
    capture_dir: str | Path,
    calibration_capture_dir: str | Path | None = None,
) -> SurfaceMeasurement:
    """:func:`measure_surface` on the black and white captures of ``capture_dir`` (named as the
    patterns of ``pattern_dir``), taken with the object in place. With ``calibration_capture_dir``
    (the captures the calibration was made from) a camera moved between the two sessions by more
    than :data:`MAX_CAMERA_SHIFT_PX` projector pixels is refused (:func:`camera_shift_px`)."""
    manifest = PatternManifest.load(pattern_dir)
    calibration.check_projector_hw((manifest.height, manifest.width), "the pattern set")
    black, white = surface_capture_files(manifest)
    captures = read_captures(capture_dir, [black, *white])
    if calibration_capture_dir is not None:
        reference = read_captures(calibration_capture_dir, [black, *white])
        shift = camera_shift_px(
            (reference[black], [reference[name] for name in white]), (captures[black], [captures[n] for n in white])
        )
        moved_px = float(np.hypot(*shift)) / calibration.camera_map.camera_pixels_per_projector_pixel()
        if moved_px > MAX_CAMERA_SHIFT_PX:
            raise EdofprojError(
                f"the camera moved between the calibration's captures and the surface captures '{capture_dir}': the "
                f"field lies {np.hypot(*shift):.2f} camera px ({moved_px:.2f} projector px; dy {shift[0]:+.2f}, dx "
                f"{shift[1]:+.2f}) from the calibration's, more than the {MAX_CAMERA_SHIFT_PX:g} projector px a "
                "surface can be read through its camera map: capture both with the camera still"
            )
    return measure_surface(calibration, captures[black], [captures[name] for name in white])
