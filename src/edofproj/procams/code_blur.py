"""The PSF's width along a coded axis, measured from the captures of the code itself.

A Gray-code plane varies along one axis of the projector only (:mod:`.structured_light`), so its
capture depends on the PSF only through the PSF's marginal along that axis. With that marginal a
Gaussian of width ``sigma`` (projector px), camera pixel ``q``, which sees the sub-pixel coordinate
``c(q)`` (:mod:`.edge_map`), sees plane ``i`` (profile ``p_i(k)`` in ``{0, 1}`` over the projector
pixels ``k`` along the axis) as

    s_i(q) = sum_k p_i(k) g(c(q) - k) / sum_k g(c(q) - k),    g(d) = exp(-d^2 / (2 sigma^2)),

the response of one lit projector pixel sampled at ``c(q)`` -- what a dot capture measures -- summed
over the lit pixels, and captures it as

    I_i(q) = alpha_i [D(q) + (B(q) - D(q)) s_i(q)] + beta_i

with ``D``, ``B`` the pixel's dark and bright levels and ``alpha_i``, ``beta_i`` the capture's gain
and offset (an exposure that changes between frames). :func:`fit_blur_width` fits ``sigma`` by
least squares over the planes' captures: first one width for the whole surface (a search over
``SIGMA_CANDIDATES_PX`` with the exposures refitted at each, then a parabola through the best three),
then one width per cell of a grid of projector points with the exposures kept. Only the pixels
within ``4 sigma`` of a plane's edge depend on ``sigma``; the others are left out of the search.

:func:`blur_psf_map` turns the widths into a :class:`.psf_map.PSFMap`: the covariance of a reference
PSF map (e.g. measured from dots in another session) with its variance along the axis replaced, its
correlation kept; without a reference, an isotropic Gaussian (the width across the axis is then
not measured: a pattern that varies along the axis only does not depend on it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import EdofprojError
from .psf_map import PSFMap
from .structured_light import CLIPPED_BLACK, SATURATED, CorrespondenceMap, axis_length, gray_code_profiles

SIGMA_CANDIDATES_PX = np.round(np.arange(0.3, 3.01, 0.1), 2)
"""Widths (projector px) searched for the blur along a coded axis."""
DEFAULT_CELL_PX = 48
"""Side (projector px) of the cells that get one blur width each."""
MIN_CELL_SAMPLES = 400
"""Fewest edge samples (pixel-plane pairs within ``4 sigma`` of an edge) for a cell's own width."""


def seen_profile(profile: np.ndarray, coordinate: np.ndarray, sigma_px) -> np.ndarray:
    """``s(q)`` of the module docstring: the 0/1 (or grey) ``profile`` ``(L,)`` along the axis seen at
    the sub-pixel ``coordinate`` (any shape, finite) through a Gaussian of width ``sigma_px``
    (scalar or the coordinate's shape); pixels beyond the profile's ends repeat its end values."""
    c = np.asarray(coordinate, dtype=np.float64)
    sigma = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), c.shape)
    radius = int(math.ceil(4.0 * float(np.max(sigma)))) + 1 if sigma.size else 1
    k0 = np.floor(c).astype(np.int64)
    total = np.zeros_like(c)
    weight = np.zeros_like(c)
    for d in range(-radius, radius + 2):
        k = k0 + d
        g = np.exp(-0.5 * ((c - k) / sigma) ** 2)
        total += g * profile[np.clip(k, 0, len(profile) - 1)]
        weight += g
    return total / weight


@dataclass
class BlurFit:
    """The blur along a coded axis: ``sigma_px`` the width over the whole surface; ``cell_sigma_px``
    ``(rows, cols)`` per cell at grid points ``ys`` x ``xs`` (projector px), ``fitted`` where a cell
    had enough edge samples (elsewhere the nearest fitted cell's); ``gains``, ``offsets`` each
    plane's exposure; ``residual`` ``(p,)`` each pixel's RMS residual over the planes (image
    units) at its cell's width."""

    sigma_px: float
    cell_sigma_px: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    fitted: np.ndarray
    gains: np.ndarray
    offsets: np.ndarray
    residual: np.ndarray


def _exposure(model: np.ndarray, capture: np.ndarray) -> tuple[float, float]:
    use = (capture < SATURATED) & (capture > CLIPPED_BLACK)
    if use.sum() < 2:
        raise EdofprojError("too few unclipped pixels to fit a capture's gain and offset")
    (alpha, beta), *_ = np.linalg.lstsq(np.c_[model[use], np.ones(int(use.sum()))], capture[use], rcond=None)
    return float(alpha), float(beta)


def _squared_errors(captures, profiles, coordinate, dark, bright, sigma, gains=None, offsets=None):
    """``(n, p)`` squared residuals and the exposures (fitted unless given)."""
    errors = np.empty(captures.shape)
    fitted_gains, fitted_offsets = np.empty(len(captures)), np.empty(len(captures))
    for i, (capture, profile) in enumerate(zip(captures, profiles)):
        model = dark + (bright - dark) * seen_profile(profile, coordinate, sigma)
        if gains is None:
            fitted_gains[i], fitted_offsets[i] = _exposure(model, capture)
        else:
            fitted_gains[i], fitted_offsets[i] = gains[i], offsets[i]
        predicted = np.clip(fitted_gains[i] * model + fitted_offsets[i], 0.0, 1.0)
        errors[i] = (predicted - capture) ** 2
    return errors, fitted_gains, fitted_offsets


def _parabola_minimum(xs: np.ndarray, ys: np.ndarray, best: int) -> float:
    if best == 0 or best == len(xs) - 1:
        return float(xs[best])
    (a, b, _), *_ = np.linalg.lstsq(np.vander(xs[best - 1 : best + 2], 3), ys[best - 1 : best + 2], rcond=None)
    return float(-b / (2 * a)) if a > 0 else float(xs[best])


def _near_edges(profiles: np.ndarray, coordinate: np.ndarray, reach_px: float) -> np.ndarray:
    """``(n, p)``: the pixels within ``reach_px`` of an edge of each plane."""
    near = np.zeros((len(profiles), len(coordinate)), dtype=bool)
    for i, profile in enumerate(profiles):
        edges = np.flatnonzero(np.diff(profile) != 0) + 0.5
        if edges.size:
            at = np.clip(np.searchsorted(edges, coordinate), 1, len(edges)) - 1
            nearest = np.minimum(
                np.abs(coordinate - edges[at]), np.abs(coordinate - edges[np.clip(at + 1, 0, len(edges) - 1)])
            )
            near[i] = nearest <= reach_px
    return near


def fit_blur_width(
    captures,
    profiles: np.ndarray,
    coordinate: np.ndarray,
    dark: np.ndarray,
    bright: np.ndarray,
    projector_hw: tuple[int, int],
    cell_coords: tuple[np.ndarray, np.ndarray] | None = None,
    cell_px: int = DEFAULT_CELL_PX,
) -> BlurFit:
    """The module docstring's fit from captures ``(n, p)`` (image units) of planes with profiles
    ``(n, L)``, at ``p`` camera pixels that see ``coordinate`` ``(p,)`` along the axis, with dark
    and bright levels ``(p,)``. Cells: ``cell_coords`` ``(x, y)`` ``(p,)`` each, the projector
    point each pixel sees (its coordinate across the axis may be unknown: NaN, then the cells are
    bands along the axis) on the ``projector_hw`` projector; None: one width for the whole surface."""
    captures = np.asarray(captures, dtype=np.float64)
    coordinate = np.asarray(coordinate, dtype=np.float64)
    if captures.ndim != 2 or captures.shape[1] != coordinate.shape[0] or len(profiles) != len(captures):
        raise EdofprojError(
            f"captures {captures.shape}, profiles {np.shape(profiles)} and {coordinate.shape} pixels do not match"
        )
    if coordinate.size < 100 or not np.all(np.isfinite(coordinate)):
        raise EdofprojError(f"{coordinate.size} pixels with a finite coordinate: too few to measure the blur")
    near = _near_edges(profiles, coordinate, 4.0 * SIGMA_CANDIDATES_PX[-1])
    columns = near.any(axis=0)
    sub = (captures[:, columns], coordinate[columns], dark[columns], bright[columns])
    totals = []
    for sigma in SIGMA_CANDIDATES_PX:
        errors, _, _ = _squared_errors(sub[0], profiles, sub[1], sub[2], sub[3], sigma)
        totals.append(errors[near[:, columns]].sum())
    best = int(np.argmin(totals))
    sigma = _parabola_minimum(SIGMA_CANDIDATES_PX, np.array(totals), best)
    _, gains, offsets = _squared_errors(captures, profiles, coordinate, dark, bright, sigma)

    H, W = projector_hw
    if cell_coords is None:
        xs, ys = np.array([0.0, W - 1.0]), np.array([0.0, H - 1.0])
        cell_sigma = np.full((2, 2), sigma)
        fitted = np.ones((2, 2), dtype=bool)
        per_pixel = np.full(coordinate.shape, sigma)
    else:
        px, py = (np.asarray(a, dtype=np.float64) for a in cell_coords)
        xs, i = _cell_axis(px, W, cell_px)
        ys, j = _cell_axis(py, H, cell_px)
        cell = j * len(xs) + i
        n_cells = len(xs) * len(ys)
        sums = np.zeros((len(SIGMA_CANDIDATES_PX), n_cells))
        count = np.bincount(np.repeat(cell[None], len(profiles), 0)[near], minlength=n_cells)
        for a, s in enumerate(SIGMA_CANDIDATES_PX):
            errors, _, _ = _squared_errors(sub[0], profiles, sub[1], sub[2], sub[3], s, gains, offsets)
            masked = np.where(near[:, columns], errors, 0.0).sum(axis=0)
            sums[a] = np.bincount(cell[columns], weights=masked, minlength=n_cells)
        values = np.full(n_cells, np.nan)
        for c in np.flatnonzero(count >= MIN_CELL_SAMPLES):
            values[c] = _parabola_minimum(SIGMA_CANDIDATES_PX, sums[:, c], int(np.argmin(sums[:, c])))
        grid = values.reshape(len(ys), len(xs))
        fitted = np.isfinite(grid)
        if not fitted.any():
            grid = np.full_like(grid, sigma)
            fitted = np.ones_like(fitted)
        smooth = ndimage.generic_filter(grid, _nanmedian, size=3, mode="nearest")
        missing = ~np.isfinite(smooth)
        if missing.any():
            _, (ny, nx) = ndimage.distance_transform_edt(missing, return_indices=True)
            smooth = smooth[ny, nx]
        cell_sigma = smooth
        per_pixel = cell_sigma.ravel()[cell]
    errors, _, _ = _squared_errors(captures, profiles, coordinate, dark, bright, per_pixel, gains, offsets)
    return BlurFit(
        sigma_px=sigma, cell_sigma_px=cell_sigma, xs=xs, ys=ys, fitted=fitted, gains=gains, offsets=offsets,
        residual=np.sqrt(errors.mean(axis=0)),
    )  # fmt: skip


def _cell_axis(coords: np.ndarray, length: int, cell_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres along one projector axis (at least two: the axis's ends when the pixels' coordinate
    along it is unknown, NaN, or the axis is shorter than two cells) and each pixel's cell index."""
    centres = np.arange(cell_px / 2, length, cell_px, dtype=np.float64).clip(max=length - 1)
    if len(centres) < 2 or not np.isfinite(coords).any():
        return np.array([0.0, length - 1.0]), np.zeros(len(coords), dtype=np.int64)
    index = np.rint((np.nan_to_num(coords, nan=centres[0]) - centres[0]) / (centres[1] - centres[0]))
    return centres, np.clip(index, 0, len(centres) - 1).astype(np.int64)


def _nanmedian(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else float("nan")


def blur_psf_map(fit: BlurFit, axis: str, projector_hw: tuple[int, int], reference: PSFMap | None = None) -> PSFMap:
    """The PSF map of the module docstring on the fit's grid (offset ``o = 0``: a map anchored to a
    Gray code has no phase origin to correct)."""
    axis_length(projector_hw, axis)  # checks the axis
    xs, ys = fit.xs, fit.ys
    variance = fit.cell_sigma_px**2
    cov = np.zeros((len(ys), len(xs), 2, 2))
    a = 0 if axis == "x" else 1
    b = 1 - a
    if reference is None:
        cov[..., 0, 0] = cov[..., 1, 1] = variance
    else:
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        ref = reference.covariance_at(xx, yy)
        correlation = ref[..., 0, 1] / np.sqrt(ref[..., 0, 0] * ref[..., 1, 1])
        cov[..., a, a] = variance
        cov[..., b, b] = ref[..., b, b]
        cov[..., 0, 1] = cov[..., 1, 0] = correlation * np.sqrt(variance * ref[..., b, b])
    hw = (int(projector_hw[0]), int(projector_hw[1]))
    return PSFMap(xs=xs, ys=ys, cov=cov, offset_px=np.zeros(2), fitted=fit.fitted.copy(), projector_hw=hw)


def measure_code_blur(
    frames,
    corr: CorrespondenceMap,
    axis: str,
    dark: np.ndarray,
    bright: np.ndarray,
    cell_px: int = DEFAULT_CELL_PX,
    flat_filter_px: int = 11,
) -> BlurFit:
    """:func:`fit_blur_width` from the first ``m`` Gray-code planes' grey captures ``(m, Hc, Wc)``
    along ``axis`` and the map of the same camera pose (its coordinate along the axis, sub-pixel:
    :mod:`.edge_map`), with the map's dark and bright levels median-filtered over
    ``flat_filter_px`` (as the prediction does); cells over the projector points the map gives."""
    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[1:] != corr.camera_hw:
        raise EdofprojError(
            f"the captures {stack.shape} are not of the map's {corr.camera_hw[1]}x{corr.camera_hw[0]} camera"
        )
    along = corr.proj_x if axis == "x" else corr.proj_y
    across = corr.proj_y if axis == "x" else corr.proj_x
    known = np.isfinite(along)
    v, u = np.nonzero(known)
    dark = ndimage.median_filter(np.asarray(dark, dtype=np.float64), size=flat_filter_px)
    bright = ndimage.median_filter(np.asarray(bright, dtype=np.float64), size=flat_filter_px)
    profiles = gray_code_profiles(axis_length(corr.projector_hw, axis))[: len(stack)]
    cells = (along[v, u], across[v, u]) if axis == "x" else (across[v, u], along[v, u])
    return fit_blur_width(
        stack[:, v, u], profiles, along[v, u], dark[v, u], bright[v, u], corr.projector_hw, cells, cell_px
    )
