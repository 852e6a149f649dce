"""Geometric calibration of a projector-camera pair from a captured dot grid (paper Sec. 5.2).

1. **Detect** the dots in the black-subtracted, lightly smoothed capture: Otsu threshold
   (:func:`skimage.filters.threshold_otsu`), connected components
   (:func:`cv2.connectedComponentsWithStats`), specks smaller than a fifth of the largest blob
   dropped; each centre is then the intensity centroid ``c = sum_i I_i q_i / sum_i I_i`` over a
   square of half the dot spacing around the blob, re-centred a few times -- sub-pixel, and
   unbiased for lopsided blobs (a threshold would cut their faint side).
2. **Match** them to the projector's grid: the four corner dots (extremes of ``u + v`` and
   ``u - v``) give a first homography; every grid dot is predicted through it and paired with
   the nearest detection (``scipy.spatial.cKDTree``); the homography is refitted on all pairs
   and the pairing repeated. Valid for a camera turned by less than about 30 degrees and not
   mirrored.
3. **Dense map**: for every projector pixel the camera coordinate that sees it,
   ``q(x) = H x + r(x)``: a least-squares homography (:func:`cv2.findHomography`) plus a
   thin-plate-spline interpolation of the dots' residuals ``r`` (lens distortion;
   :class:`scipy.interpolate.RBFInterpolator`).
4. **Warp** a capture into projector pixels by bilinear interpolation at ``q(x)``
   (:func:`cv2.remap`), paper Sec. 5.2.

The blobs are the dots blurred by the projector's PSF, so their centroids carry the PSF's
centroid: a PSF measured with this map is centred on its own centroid (the optical axis for
any radially symmetric DOE).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.interpolate import RBFInterpolator
from scipy.spatial import cKDTree
from skimage.filters import threshold_otsu

from ..errors import EdofprojError

MIN_CAMERA_PIXELS_PER_PROJECTOR_PIXEL = 2.0
"""Below this magnification the camera's own sampling visibly blurs a measured PSF: warn."""


def apply_homography(homography: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(n, 2)`` points mapped by a 3x3 homography (homogeneous division)."""
    points = np.asarray(points, dtype=np.float64)
    mapped = np.c_[points, np.ones(len(points))] @ np.asarray(homography, dtype=np.float64).T
    return mapped[:, :2] / mapped[:, 2:3]


def detect_dots(
    gray: np.ndarray, min_area_fraction: float = 0.2, smoothing_px: float = 1.5, refinements: int = 3
) -> np.ndarray:
    """Sub-pixel centres ``(n, 2)`` as ``(u, v)`` of the bright blobs of a black-subtracted grey image.

    Blobs: the image smoothed by a Gaussian of ``smoothing_px`` (noise), thresholded at Otsu's
    level; blobs smaller than ``min_area_fraction`` of the largest are dropped. Centres: the
    intensity centroid ``sum_i I_i q_i / sum_i I_i`` of the unthresholded image over a square of
    half the distance to the nearest other blob, re-centred ``refinements`` times -- a
    threshold would cut a lopsided blob's faint side and move its centroid.
    """
    gray = np.asarray(gray, dtype=np.float64)
    if gray.size == 0 or np.ptp(gray) <= 0:
        return np.zeros((0, 2))
    smooth = cv2.GaussianBlur(gray, (0, 0), smoothing_px)
    mask = (smooth > threshold_otsu(smooth)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    if areas.size == 0:
        return np.zeros((0, 2))
    keep = np.flatnonzero(areas >= min_area_fraction * areas.max()) + 1
    centres = np.asarray(ndimage.center_of_mass(mask, labels, keep), dtype=np.float64).reshape(-1, 2)[:, ::-1]
    if len(centres) < 2:
        return centres
    half = max(2, int(0.5 * np.min(cKDTree(centres).query(centres, k=2)[0][:, 1])))
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    for _ in range(refinements):
        for n, (u, v) in enumerate(centres):
            cu, cv = int(round(u)), int(round(v))
            u0, u1 = max(cu - half, 0), min(cu + half + 1, gray.shape[1])
            v0, v1 = max(cv - half, 0), min(cv + half + 1, gray.shape[0])
            weights = smooth[v0:v1, u0:u1]
            total = weights.sum()
            if total > 0:
                centres[n] = [
                    (weights.sum(axis=0) @ (offsets[u0 - cu + half : u1 - cu + half] + cu)) / total,
                    (weights.sum(axis=1) @ (offsets[v0 - cv + half : v1 - cv + half] + cv)) / total,
                ]
    return centres


def _pair_with_grid(predicted: np.ndarray, detected: np.ndarray, spacing_px: float) -> np.ndarray | None:
    """Index of the detection nearest each predicted dot, or None if pairs are ambiguous or far."""
    distance, index = cKDTree(detected).query(predicted)
    if len(np.unique(index)) != len(index) or np.max(distance) > 0.4 * spacing_px:
        return None
    return index


def match_grid(detected: np.ndarray, grid_proj: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The detections ordered like ``grid_proj`` (row-major ``rows x cols``), ``(rows * cols, 2)``."""
    grid = np.asarray(grid_proj, dtype=np.float64).reshape(rows, cols, 2)
    corner_proj = np.array([grid[0, 0], grid[0, -1], grid[-1, -1], grid[-1, 0]])
    s, d = detected.sum(axis=1), detected[:, 0] - detected[:, 1]
    corner_cam = detected[[np.argmin(s), np.argmax(d), np.argmax(s), np.argmin(d)]]
    homography = cv2.getPerspectiveTransform(corner_proj.astype(np.float32), corner_cam.astype(np.float32))
    flat = grid.reshape(-1, 2)
    for _ in range(2):
        predicted = apply_homography(homography, flat)
        spacing = np.min(np.linalg.norm(np.diff(predicted.reshape(rows, cols, 2), axis=1), axis=-1))
        spacing = min(spacing, np.min(np.linalg.norm(np.diff(predicted.reshape(rows, cols, 2), axis=0), axis=-1)))
        index = _pair_with_grid(predicted, detected, spacing)
        if index is None:
            raise EdofprojError(
                f"could not match the {len(detected)} detected dots to the {rows}x{cols} grid "
                "(is the camera turned by more than ~30 degrees, or mirrored?)"
            )
        homography, _ = cv2.findHomography(flat, detected[index], 0)
    return detected[index]


@dataclass
class CameraMap:
    """For every projector pixel ``(H, W)``, the camera coordinate ``(map_x, map_y)`` that sees its centre.

    Also kept: the fitted ``homography`` (projector -> camera), the dot correspondences and the
    camera's size ``camera_hw``.
    """

    map_x: np.ndarray
    map_y: np.ndarray
    homography: np.ndarray
    dots_proj: np.ndarray
    dots_cam: np.ndarray
    camera_hw: tuple[int, int]

    @property
    def projector_hw(self) -> tuple[int, int]:
        return tuple(self.map_x.shape)

    def warp(self, capture: np.ndarray) -> np.ndarray:
        """A camera image ``(Hc, Wc, C)`` resampled into projector pixels ``(H, W, C)`` (bilinear)."""
        if tuple(capture.shape[:2]) != tuple(self.camera_hw):
            raise EdofprojError(
                f"capture is {capture.shape[0]}x{capture.shape[1]} pixels, the calibrated camera "
                f"{self.camera_hw[0]}x{self.camera_hw[1]} (height x width)"
            )
        warped = cv2.remap(
            np.asarray(capture, dtype=np.float32),
            self.map_x.astype(np.float32),
            self.map_y.astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        return warped.reshape(self.projector_hw + capture.shape[2:])

    def homography_residual_px(self) -> np.ndarray:
        """Distance (camera px) of each dot from the homography alone: the lens distortion seen."""
        return np.linalg.norm(self.dots_cam - apply_homography(self.homography, self.dots_proj), axis=1)

    def camera_pixels_per_projector_pixel(self) -> float:
        """Smallest linear magnification ``sqrt|det J|`` of the map over the projector image."""
        jacobian = [np.gradient(m, axis=a) for m in (self.map_x, self.map_y) for a in (1, 0)]
        return float(np.sqrt(np.abs(jacobian[0] * jacobian[3] - jacobian[1] * jacobian[2])).min())


def fit_camera_map(
    dots_proj: np.ndarray, dots_cam: np.ndarray, projector_hw: tuple[int, int], camera_hw: tuple[int, int]
) -> CameraMap:
    """The dense map ``q(x) = H x + r(x)`` (module docstring, step 3) from dot correspondences."""
    dots_proj = np.asarray(dots_proj, dtype=np.float64)
    dots_cam = np.asarray(dots_cam, dtype=np.float64)
    homography, _ = cv2.findHomography(dots_proj, dots_cam, 0)
    if homography is None:
        raise EdofprojError("the dot correspondences do not determine a homography (degenerate grid)")
    residual = dots_cam - apply_homography(homography, dots_proj)
    spline = RBFInterpolator(dots_proj, residual, kernel="thin_plate_spline")
    H, W = projector_hw
    y, x = np.mgrid[0:H, 0:W]
    pixels = np.c_[x.ravel(), y.ravel()].astype(np.float64)
    mapped = apply_homography(homography, pixels) + spline(pixels)
    return CameraMap(
        map_x=mapped[:, 0].reshape(H, W),
        map_y=mapped[:, 1].reshape(H, W),
        homography=homography,
        dots_proj=dots_proj,
        dots_cam=dots_cam,
        camera_hw=(camera_hw[0], camera_hw[1]),
    )


def calibrate_geometry(
    dots_capture: np.ndarray,
    black_capture: np.ndarray,
    dots_proj: np.ndarray,
    grid: tuple[int, int],
    projector_hw: tuple[int, int],
) -> CameraMap:
    """The camera map from the captures of the dot grid and of the black field.

    Raises one line when the number of blobs found differs from the grid's, or when the camera
    does not see the whole projector image; warns when the camera resolves a projector pixel
    with fewer than :data:`MIN_CAMERA_PIXELS_PER_PROJECTOR_PIXEL` pixels.
    """
    rows, cols = grid
    gray = (np.asarray(dots_capture, np.float64) - np.asarray(black_capture, np.float64)).mean(axis=-1)
    detected = detect_dots(gray)
    if len(detected) != rows * cols:
        raise EdofprojError(
            f"found {len(detected)} dots in the dot-grid capture, expected {rows}x{cols} = {rows * cols} "
            "(blobs merged, cut by the image border, or too faint: try fewer dots or a longer exposure)"
        )
    camera_map = fit_camera_map(
        dots_proj, match_grid(detected, dots_proj, rows, cols), projector_hw, black_capture.shape[:2]
    )
    Hc, Wc = camera_map.camera_hw
    outside = (
        (camera_map.map_x < 0) | (camera_map.map_x > Wc - 1) | (camera_map.map_y < 0) | (camera_map.map_y > Hc - 1)
    )
    if np.any(outside):
        raise EdofprojError(
            f"the camera does not see the whole projector image: {100 * outside.mean():.1f} % of the projector "
            "pixels fall outside the camera frame"
        )
    magnification = camera_map.camera_pixels_per_projector_pixel()
    if magnification < MIN_CAMERA_PIXELS_PER_PROJECTOR_PIXEL:
        warnings.warn(
            f"the camera resolves a projector pixel with only {magnification:.2f} camera pixels (>= 3 recommended): "
            "measured PSFs will be widened by the camera's sampling",
            stacklevel=2,
        )
    return camera_map
