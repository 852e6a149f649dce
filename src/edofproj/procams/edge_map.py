"""A Gray code's stripe edges located to a fraction of a camera pixel, and the smooth surface through
them: the camera -> projector coordinate along the code's axis with sub-pixel precision.

Decoding ``m`` planes (:func:`.structured_light.decode_gray_code`) tells each camera pixel its
stripe, ``w = 2^(n - m)`` projector px wide: the coordinate is known to ``+- w / 2``. The stripes'
*edges* are known exactly in projector coordinates: the boundary between stripes ``s`` and
``s + 1`` is at ``c = (s + 1) w - 1/2`` (between two pixel centres), and it is an edge of the one
plane ``k`` whose Gray bit differs between the two stripes. Three steps:

1. **Edges** (:func:`locate_edges`). Each plane, brought to one exposure
   (:func:`.structured_light.normalize_exposures`), is normalized per pixel,
   ``t_k(q) = (I_k(q) - D(q)) / (B(q) - D(q)) - 1/2`` with ``D``, ``B`` the pixels' dark and bright
   levels (median-filtered); along each camera line that crosses the stripes, a sign change of
   ``t_k`` between neighbours ``u`` and ``u + 1`` is an edge at ``u* = u + t_k(u) / (t_k(u) - t_k(u + 1))``
   (linear interpolation), kept where the stripes decoded ``probe_px`` before and after it are
   neighbours whose Gray codes differ in plane ``k`` -- the edge has a known coordinate ``c``.
   A symmetric blur puts the half level on the edge.
2. **Surface** (:func:`fit_edge_surface`). A plane seen by two pinholes maps camera pixels to the
   projector coordinate by one row of a homography, ``c(u, v) = (a u + b v + c0) / (g u + h v + 1)``
   (normalized camera coordinates). It is fitted to the edge points by RANSAC
   (:func:`skimage.measure.ransac`, threshold ``ransac_px``: the points of another surface, a wall
   behind the board, are dropped), then corrected by a smooth bicubic spline of the residuals
   (:class:`scipy.interpolate.LSQBivariateSpline`, knots every ``knot_spacing_px`` camera px: the
   lens's distortion, a board that is not flat), refitted over the points within ``inlier_px``.
   Each edge point is one noisy measurement; the surface averages tens of thousands of them.
3. **Validity** (:func:`decode_gray_code_edges`). A pixel gets the surface's coordinate where its
   decoded stripe agrees with it (within half a stripe and ``agree_px``), an inlier edge is within
   ``reach_px`` camera px, and the decoded planes' captures are explained there: seen through the
   blur along the axis (:mod:`.code_blur`, one width fitted over the surface), each pixel's RMS
   residual over the planes, median-filtered over ``filter_px``, is at most ``max_residual``
   (image units) -- the board's border, where a pixel sees both the board and what lies behind it,
   and specks on the board fail it. The dark and bright levels are the planes' per-pixel minimum and
   maximum after :func:`.structured_light.normalize_exposures`, those of the pixels without contrast
   taken from their nearest neighbour with it (:func:`fill_levels`).

The edges are searched along the camera's rows when the decoded coordinate changes faster along
them than along its columns, else along its columns.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.interpolate import LSQBivariateSpline
from skimage.measure import ransac

from ..errors import EdofprojError
from .code_blur import fit_blur_width
from .structured_light import (
    DEFAULT_MIN_CONTRAST,
    AxisDecoding,
    decode_gray_code,
    gray_code_bits,
    gray_code_profiles,
    normalize_exposures,
)

DEFAULT_MAX_RESIDUAL = 12.0 / 255.0
"""Largest RMS residual (image units) of the decoded planes' captures at a valid pixel."""


@dataclass
class EdgePoints:
    """Edge points: camera position ``(u, v)`` (px, sub-pixel along the search direction), the
    projector ``coordinate`` of the edge, the ``plane`` it belongs to (0-based), and ``rising``
    (the lit side is at the larger camera position). 1-D arrays of one length."""

    u: np.ndarray
    v: np.ndarray
    coordinate: np.ndarray
    plane: np.ndarray
    rising: np.ndarray

    def subset(self, keep: np.ndarray) -> "EdgePoints":
        return EdgePoints(self.u[keep], self.v[keep], self.coordinate[keep], self.plane[keep], self.rising[keep])


def _along_rows(decoding: AxisDecoding) -> bool:
    """Whether the decoded coordinate changes more along the camera's rows (``u``) than its columns."""
    c = decoding.coordinate
    du, dv = (np.abs(np.diff(c, axis=a)) for a in (1, 0))
    along_u = float(np.mean(du[np.isfinite(du)])) if np.isfinite(du).any() else 0.0
    along_v = float(np.mean(dv[np.isfinite(dv)])) if np.isfinite(dv).any() else 0.0
    return along_u >= along_v


def locate_edges(
    normalized: np.ndarray,
    dark: np.ndarray,
    bright: np.ndarray,
    decoding: AxisDecoding,
    length_px: int,
    probe_px: int = 3,
    min_contrast: float = DEFAULT_MIN_CONTRAST,
) -> EdgePoints:
    """Step 1 of the module docstring, for ``m`` planes' captures ``(m, Hc, Wc)`` brought to one
    exposure, their dark and bright levels ``(Hc, Wc)`` and their decoding."""
    normalized = np.asarray(normalized, dtype=np.float64)
    m = len(normalized)
    n = gray_code_bits(length_px)
    width = 2 ** (n - m)
    rows = _along_rows(decoding)
    stripe = np.where(decoding.valid, np.rint((np.nan_to_num(decoding.coordinate) - (width - 1) / 2) / width), -1)
    stripe = stripe.astype(np.int64)
    contrast_ok = (bright - dark) >= min_contrast
    if not rows:  # search along the camera's columns: work on the transposed images
        normalized, dark, bright = normalized.transpose(0, 2, 1), dark.T, bright.T
        stripe, contrast_ok = stripe.T, contrast_ok.T
    count = 2**m
    gray = np.arange(count) ^ (np.arange(count) >> 1)
    span = np.maximum(bright - dark, 1e-9)
    found = []
    for k in range(m):
        t = (normalized[k] - dark) / span - 0.5
        a, b = t[:, :-1], t[:, 1:]
        cross = (np.signbit(a) != np.signbit(b)) & contrast_ok[:, :-1] & contrast_ok[:, 1:]
        line, pos = np.nonzero(cross)
        inside = (pos >= probe_px) & (pos + 1 + probe_px < t.shape[1])
        line, pos = line[inside], pos[inside]
        before, after = stripe[line, pos - probe_px], stripe[line, pos + 1 + probe_px]
        good = (before >= 0) & (after >= 0) & (np.abs(before - after) == 1)
        low, high = np.minimum(before, after), np.maximum(before, after)
        differs = (gray[np.clip(low, 0, count - 1)] ^ gray[np.clip(high, 0, count - 1)]) >> (m - 1 - k)
        good &= (differs & 1) == 1
        line, pos, high = line[good], pos[good], high[good]
        ta, tb = t[line, pos], t[line, pos + 1]
        found.append((pos + ta / (ta - tb), line.astype(np.float64), high * width - 0.5, np.full(len(pos), k), tb > ta))
    along, across, coordinate, plane, rising = (np.concatenate(parts) for parts in zip(*found))
    u, v = (along, across) if rows else (across, along)
    return EdgePoints(u=u, v=v, coordinate=coordinate, plane=plane.astype(np.int64), rising=rising.astype(bool))


class _HomographyRow:
    """``c = (a u + b v + c0) / (g u + h v + 1)`` in normalized coordinates, for :func:`skimage.measure.ransac`."""

    def __init__(self, params: np.ndarray | None = None) -> None:
        self.params = params

    @classmethod
    def from_estimate(cls, data: np.ndarray) -> "_HomographyRow":
        u, v, c = data.T
        A = np.c_[u, v, np.ones_like(u), -c * u, -c * v]
        params, *_ = np.linalg.lstsq(A, c, rcond=None)
        return cls(params)

    def __bool__(self) -> bool:
        return self.params is not None and bool(np.all(np.isfinite(self.params)))

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a, b, c0, g, h = self.params  # type: ignore[misc]
        return (a * u + b * v + c0) / (g * u + h * v + 1.0)

    def residuals(self, data: np.ndarray) -> np.ndarray:
        return np.abs(self(data[:, 0], data[:, 1]) - data[:, 2])


@dataclass
class EdgeSurface:
    """Step 2's surface: the homography row ``params`` ``(a, b, c0, g, h)`` and the spline correction
    (None: none), in camera coordinates normalized to ``[-1, 1]`` over ``camera_hw``."""

    params: np.ndarray
    spline: LSQBivariateSpline | None
    camera_hw: tuple[int, int]

    def _normalized(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Hc, Wc = self.camera_hw
        return 2.0 * np.asarray(u, float) / max(Wc - 1, 1) - 1.0, 2.0 * np.asarray(v, float) / max(Hc - 1, 1) - 1.0

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The projector coordinate at camera points ``(u, v)`` (px, any shape)."""
        un, vn = self._normalized(u, v)
        value = _HomographyRow(self.params)(un, vn)
        if self.spline is not None:
            value = value + self.spline.ev(un.ravel(), vn.ravel()).reshape(un.shape)
        return value

    def grid(self) -> np.ndarray:
        """``(Hc, Wc)``: the surface at every camera pixel."""
        v, u = np.mgrid[0 : self.camera_hw[0], 0 : self.camera_hw[1]]
        return self(u, v)


def fit_edge_surface(
    edges: EdgePoints,
    camera_hw: tuple[int, int],
    ransac_px: float = 2.0,
    inlier_px: float = 0.6,
    knot_spacing_px: float = 128.0,
    seed: int = 0,
) -> tuple[EdgeSurface, np.ndarray]:
    """Step 2 of the module docstring: the surface and the inlier edge points (bool, per point)."""
    if len(edges.u) < 50:
        raise EdofprojError(f"{len(edges.u)} stripe edges found: too few to fit the map (are the stripes in focus?)")
    surface = EdgeSurface(np.zeros(5), None, (int(camera_hw[0]), int(camera_hw[1])))
    un, vn = surface._normalized(edges.u, edges.v)
    data = np.c_[un, vn, edges.coordinate]
    model, inliers = ransac(
        data, _HomographyRow, min_samples=5, residual_threshold=ransac_px, max_trials=2000,
        rng=np.random.default_rng(seed),
    )  # fmt: skip
    if model is None or inliers is None or inliers.sum() < 50:
        raise EdofprojError("no plane fits the stripe edges: the code's captures are not of one surface")
    Hc, Wc = surface.camera_hw
    for threshold in (ransac_px, inlier_px, inlier_px):
        row = _HomographyRow.from_estimate(data[inliers])
        base = row(un, vn)
        residual = edges.coordinate - base
        lo_u, hi_u = un[inliers].min(), un[inliers].max()
        lo_v, hi_v = vn[inliers].min(), vn[inliers].max()
        knots_u = np.arange(lo_u, hi_u, 2 * knot_spacing_px / max(Wc - 1, 1))[1:]
        knots_v = np.arange(lo_v, hi_v, 2 * knot_spacing_px / max(Hc - 1, 1))[1:]
        spline = None
        if len(knots_u) and len(knots_v) and inliers.sum() > 16 * (len(knots_u) + 4) * (len(knots_v) + 4):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # empty knot cells: least-norm coefficients there
                spline = LSQBivariateSpline(
                    un[inliers], vn[inliers], residual[inliers], knots_u, knots_v, kx=3, ky=3,
                    bbox=[lo_u, hi_u, lo_v, hi_v],
                )  # fmt: skip
        surface = EdgeSurface(row.params, spline, surface.camera_hw)  # type: ignore[arg-type]
        inliers = np.abs(surface(edges.u, edges.v) - edges.coordinate) <= threshold
    return surface, inliers


def fill_levels(dark: np.ndarray, bright: np.ndarray, window_px: int = 33) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel dark and bright levels ``(Hc, Wc)`` where the pixels with less than 90 % of the largest
    contrast ``bright - dark`` within ``window_px`` take those of the nearest pixel with more. The
    first ``m`` planes leave two stripes without contrast -- the one lit in all of them and the one
    dark in all -- each a band as wide as a stripe, whose one level says nothing of the other; a
    median filter would carry the wrong level into the neighbouring stripes."""
    contrast = bright - dark
    flat = contrast < 0.9 * ndimage.maximum_filter(contrast, size=window_px)
    if not flat.any() or flat.all():
        return dark, bright
    _, (iy, ix) = ndimage.distance_transform_edt(flat, return_indices=True)
    return dark[iy, ix], bright[iy, ix]


@dataclass
class EdgeDecoding:
    """The result of :func:`decode_gray_code_edges`: ``decoding`` (sub-pixel ``coordinate``, the
    valid pixels of step 3, the dark and bright levels in the exposure-normalized units), the
    ``edges`` and which are ``inliers``, the ``surface``, the blur width ``sigma_px`` along the axis,
    and ``residual`` ``(Hc, Wc)``: each pixel's RMS residual over the planes (NaN where untested)."""

    decoding: AxisDecoding
    edges: EdgePoints
    inliers: np.ndarray
    surface: EdgeSurface
    sigma_px: float
    residual: np.ndarray


def decode_gray_code_edges(
    frames,
    length_px: int,
    projector_hw: tuple[int, int],
    min_contrast: float = DEFAULT_MIN_CONTRAST,
    max_residual: float = DEFAULT_MAX_RESIDUAL,
    agree_px: float = 1.0,
    reach_px: float = 16.0,
    filter_px: int = 15,
    flat_filter_px: int = 11,
) -> EdgeDecoding:
    """The module docstring's three steps for the first ``m`` planes' grey captures ``(m, Hc, Wc)``
    (image units, most significant first, without inverse patterns) of a code along an axis of
    ``length_px`` of the ``projector_hw`` projector."""
    stack = np.asarray(frames, dtype=np.float64)
    decoding = decode_gray_code(stack, length_px, min_contrast=min_contrast)
    normalized = normalize_exposures(stack, min_contrast)
    dark, bright = fill_levels(normalized.min(axis=0), normalized.max(axis=0), 3 * flat_filter_px)
    levels = (dark, bright)
    dark = ndimage.median_filter(dark, size=flat_filter_px)
    bright = ndimage.median_filter(bright, size=flat_filter_px)
    edges = locate_edges(normalized, dark, bright, decoding, length_px, min_contrast=min_contrast)
    surface, inliers = fit_edge_surface(edges, decoding.coordinate.shape)  # type: ignore[arg-type]
    coordinate = surface.grid()
    width = 2 ** (gray_code_bits(length_px) - len(stack))
    hit = np.zeros(decoding.coordinate.shape, dtype=bool)
    hit[np.rint(edges.v[inliers]).astype(np.int64), np.rint(edges.u[inliers]).astype(np.int64)] = True
    near = ndimage.distance_transform_edt(~hit) <= reach_px
    gap = np.abs(np.nan_to_num(coordinate - decoding.coordinate, nan=np.inf))
    candidate = decoding.valid & near & (gap <= width / 2 + agree_px)
    candidate &= (coordinate > -0.5) & (coordinate < length_px - 0.5)
    if candidate.sum() < 100:
        raise EdofprojError(f"{candidate.sum()} camera pixels agree with the stripe edges' surface: too few")
    v, u = np.nonzero(candidate)
    profiles = gray_code_profiles(length_px)[: len(stack)]
    blur = fit_blur_width(stack[:, v, u], profiles, coordinate[v, u], dark[v, u], bright[v, u], projector_hw)
    residual = np.full(coordinate.shape, np.nan)
    residual[v, u] = blur.residual
    smooth = ndimage.median_filter(np.nan_to_num(residual, nan=1.0), size=filter_px)
    valid = candidate & (smooth <= max_residual)
    result = AxisDecoding(np.where(valid, coordinate, np.nan), valid, levels[0], levels[1])
    return EdgeDecoding(result, edges, inliers, surface, blur.sigma_px, residual)
