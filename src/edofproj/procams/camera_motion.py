"""A camera moved between two sessions: the map of the first session carried over to the second.

The map of session A (fine, both axes, :mod:`.structured_light`) is carried to session B, where
only a coarse code was captured (e.g. the first planes of a Gray code along ``x``), in two steps:

1. **Motion**: the homography ``G`` from B's camera pixels to A's that aligns what the camera sees
   with the projector fully on in both sessions (the decodings' ``bright`` levels; A's pixels that
   see B's first Gray-code stripe, never lit in B, set to black as B saw them), by
   :func:`cv2.findTransformECC` (enhanced correlation, invariant to gain and offset) from coarse
   to fine resolution, starting from the translation of
   :func:`skimage.registration.phase_cross_correlation`; then ``P_B(q) = P_A(G q)``
   (:meth:`.structured_light.CorrespondenceMap.moved`). Exact for a camera turned about its centre
   or moved in front of a plane;
2. **Anchor**: the carried map's coded axis corrected by a smooth field fitted to B's coarse
   code (:func:`.structured_light.anchor_to_code`) over the pixels where the two agree within two
   stripes (the surface that was there in both sessions), then twice more over those that agree
   within ``agree_stripes`` stripes after the previous fit; B's valid pixels are the last set.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.registration import phase_cross_correlation

from ..errors import EdofprojError
from .structured_light import AxisDecoding, CorrespondenceMap, anchor_to_code


def _pyramid_level(image: np.ndarray, scale: int, blur_px: float) -> np.ndarray:
    small = cv2.resize(np.nan_to_num(image).astype(np.float32), None, fx=1 / scale, fy=1 / scale,
                       interpolation=cv2.INTER_AREA)  # fmt: skip
    return cv2.GaussianBlur(small, (0, 0), blur_px)


def camera_motion(reference: np.ndarray, moved: np.ndarray, min_side_px: int = 48) -> np.ndarray:
    """3x3 homography ``G`` from ``moved``'s pixels to ``reference``'s (both grey ``(Hc, Wc)``,
    the same scene), module docstring step 1: image sizes reduced 8, 4, 2 times (those that keep
    at least ``min_side_px`` per side), coarse to fine."""
    if reference.shape != moved.shape:
        raise EdofprojError(f"the two sessions' images differ in size: {reference.shape} and {moved.shape}")
    scales = tuple(s for s in (8, 4, 2) if min(reference.shape) / s >= min_side_px) or (1,)
    reference, moved = np.nan_to_num(reference), np.nan_to_num(moved)
    coarse = scales[0]
    # moved(q) ~ reference(q - s): G starts as the translation by -s
    shift, _, _ = phase_cross_correlation(_pyramid_level(moved, coarse, 1.0), _pyramid_level(reference, coarse, 1.0))
    warp = np.array([[1, 0, -shift[1] * coarse], [0, 1, -shift[0] * coarse], [0, 0, 1]], dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-7)
    for scale in scales:
        S = np.diag([1.0 / scale, 1.0 / scale, 1.0])
        small = (S @ warp @ np.linalg.inv(S)).astype(np.float32)
        try:
            # findTransformECC(template, input): input(W q) ~ template(q), W: moved pixels -> reference pixels;
            # inputMask=None is valid OpenCV but missing from its stubs
            _, small = cv2.findTransformECC(  # type: ignore[call-overload]
                _pyramid_level(moved, scale, 1.0), _pyramid_level(reference, scale, 1.0), small,
                cv2.MOTION_HOMOGRAPHY, criteria, None, 5,
            )  # fmt: skip
        except cv2.error as exc:
            reason = str(exc).strip().splitlines()[-1]
            raise EdofprojError(
                f"the two sessions' images could not be aligned (is it the same scene?): {reason}"
            ) from None
        warp = np.linalg.inv(S) @ small.astype(np.float64) @ S
    return warp / warp[2, 2]


def carry_map(
    reference: CorrespondenceMap,
    reference_bright: np.ndarray,
    decoding: AxisDecoding,
    axis: str,
    bright: np.ndarray,
    degree: int = 3,
    agree_stripes: float = 0.75,
) -> tuple[CorrespondenceMap, np.ndarray]:
    """Session A's map carried to session B (module docstring); returns the map and ``G``."""
    coords = decoding.coordinate[decoding.valid]
    widths = np.diff(np.unique(coords))
    stripe = float(np.median(widths)) if widths.size else 1.0
    theirs = reference.proj_x if axis == "x" else reference.proj_y
    # the first stripe is dark in every plane of a Gray code: this session saw it dark
    unseen = np.nan_to_num(theirs, nan=np.inf) < stripe - 0.5
    G = camera_motion(np.where(unseen, 0.0, reference_bright), bright)
    moved = reference.moved(G)
    mine = moved.proj_x if axis == "x" else moved.proj_y
    near = (
        decoding.valid & np.isfinite(mine) & (np.abs(np.nan_to_num(mine - decoding.coordinate, nan=1e9)) <= 2 * stripe)
    )
    if near.sum() < 100:
        raise EdofprojError("the carried map agrees with this session's code nowhere: the motion estimate failed")
    for tolerance in (2.0, agree_stripes, agree_stripes):
        subset = AxisDecoding(np.where(near, decoding.coordinate, np.nan), near, decoding.dark, decoding.bright)
        anchored, _ = anchor_to_code(moved, subset, axis, degree)
        fixed = anchored.proj_x if axis == "x" else anchored.proj_y
        gap = np.abs(np.nan_to_num(fixed - decoding.coordinate, nan=1e9))
        near = decoding.valid & np.isfinite(fixed) & (gap <= tolerance * stripe)
    ok = near
    out = CorrespondenceMap(
        np.where(ok, anchored.proj_x, np.nan), np.where(ok, anchored.proj_y, np.nan), reference.projector_hw
    )
    return out, G
