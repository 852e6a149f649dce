"""The PSF across the surface, in projector pixels, from a captured grid of single-pixel dots.

A dot is one lit projector pixel at ``d = (x_d, y_d)`` (a grid with spacing ``s``: ``x_d = i s``,
``y_d = j s``). A camera pixel ``q`` sees the projector point ``P(q)`` (the decoded map,
:mod:`.structured_light`), so around each dot the capture is modelled in projector pixels as an
anisotropic Gaussian plus a background,

    I(q) = b + a exp(-1/2 r^T S^-1 r),   r = P(q) - d - o - c,   S = R(theta) diag(s1^2, s2^2) R(theta)^T,

with ``o`` one offset for the whole grid and ``c`` the dot's own small residual. ``S`` is the PSF's
covariance in projector pixels: its marginal widths along the projector's columns and rows are
``sigma_x = sqrt(S_xx)`` and ``sigma_y = sqrt(S_yy)``; a tilted screen makes them differ, and a
screen tilted about an oblique axis turns the ellipse (``theta``).

**Censoring.** A censored sample is a bound at its own value, never a value: a sample ``v`` marked
saturated (a grey value that averages a saturated channel, or is itself at the top) only says
``I >= v``, one marked clipped (a channel it averages is clipped to black) only ``I <= v``; they enter
the least-squares fit (:func:`scipy.optimize.least_squares`) as one-sided residuals
``max(0, v - model)`` and ``max(0, model - v)``. A dot whose core is saturated is then measured by its
unsaturated flanks. (A grey whose red channel saturates while green and blue do not is a lower bound
at its own value, not at the top of the range: demanding the top there puts a false edge at the
rim of the region where any channel saturates, and the Gaussian fitted across it is too narrow.)

**The offset.** A rig whose phase-shift patterns put the phase origin elsewhere than pixel centre 0
(e.g. 1-based columns) decodes ``P`` shifted by a constant. ``o`` is estimated, not assumed: every
dot is first fitted with a free centre over a window of half the spacing, and ``o`` is the median
of ``centre - d``; the dots are then fitted again about ``d + o``.

**The map.** The fitted covariances on the dot grid, median-filtered over about ``180 x 180``
projector px (:data:`DEFAULT_SMOOTH_PX`; :func:`smooth_covariances`: the medians of ``log sigma_x``, ``log sigma_y`` and the correlation
``rho = S_xy / (sigma_x sigma_y)``, which always give a covariance; a blur that varies with the
surface's depth changes over many dots, a single dot's fit scatters by its noise), gaps filled from
the nearest fitted dot; between dots the covariance is interpolated bilinearly (a convex combination
of covariances is a covariance). :class:`PSFMap` is saved as ``.npz``
(format ``edofproj-procams-psf-map``); one file holds a map per colour (``mean`` for white dots,
``red``, ``green``, ``blue``), each fitted from that colour's dot capture on its own grid
(:func:`save_psf_maps`, :func:`load_psf_maps`, :func:`psf_maps_for_rgb`).

**Pixel indices.** The map is in projector pixel indices (column ``x``, row ``y``), whatever the
projector's pixel layout: on a diamond (DMD) array whose rows are half a column pitch apart, a
round blur on the surface has ``sigma_y`` about twice ``sigma_x``, which the anisotropic Gaussian
carries like any other anisotropy.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import least_squares

from ..errors import EdofprojError
from ..fileio import read_arrays, read_tagged_arrays, save_npz_atomic
from ..progress import StageProgress
from .structured_light import CorrespondenceMap

PSF_MAP_FORMAT = "edofproj-procams-psf-map"
KERNEL_MAP_FORMAT = "edofproj-procams-kernel-map"
"""The other kind of PSF map file: measured kernels at nodes (:mod:`.kernel_map`)."""
PSF_MAP_CHANNELS = ("mean", "red", "green", "blue")
"""The colours a PSF map file holds maps for, in file order (``mean``: white dots, grey = mean of R, G, B)."""
MAX_SIGMA_PX = 20.0
"""Largest PSF width (projector px) a fit may return."""


def covariance(sigma1: float, sigma2: float, theta: float) -> np.ndarray:
    """``S = R(theta) diag(sigma1^2, sigma2^2) R(theta)^T`` (2x2, projector px^2)."""
    c, s = math.cos(theta), math.sin(theta)
    rotation = np.array([[c, -s], [s, c]])
    return rotation @ np.diag([sigma1**2, sigma2**2]) @ rotation.T


@dataclass
class DotFit:
    """One dot's fit: ``amplitude`` and ``background`` (image units), ``centre`` ``(x, y)`` in projector
    px, ``cov`` 2x2 (projector px^2), the samples used and the censored ones among them."""

    amplitude: float
    background: float
    centre: np.ndarray
    cov: np.ndarray
    samples: int
    censored: int


def _model(params: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    a, b, cx, cy, log_s1, log_s2, theta = params
    S = covariance(math.exp(log_s1), math.exp(log_s2), theta)
    inv = np.linalg.inv(S)
    dx, dy = px - cx, py - cy
    return b + a * np.exp(-0.5 * (inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy))


def fit_dot(
    px: np.ndarray,
    py: np.ndarray,
    values: np.ndarray,
    high: np.ndarray,
    low: np.ndarray,
    centre: tuple[float, float],
    top: float,
    sigma0: float = 1.5,
) -> DotFit | None:
    """Fit the module docstring's model to samples at projector points ``(px, py)`` (1-D arrays)
    with values ``values``; ``high`` marks samples that are lower bounds at their own value
    (saturated), ``low`` upper bounds at their own value (clipped to black): both censored. None
    when the fit does not converge or the dot has fewer than 8 uncensored samples."""
    fitted = ~(high | low)
    if fitted.sum() < 8:
        return None
    b0 = float(np.percentile(values[fitted], 10))
    a0 = max(float(values.max()) - b0, 1e-3)
    x0 = np.array([a0, b0, centre[0], centre[1], math.log(sigma0), math.log(sigma0), 0.0])
    lower = [0.0, -top, centre[0] - 3, centre[1] - 3, math.log(0.2), math.log(0.2), -math.pi]
    upper = [50 * top, top, centre[0] + 3, centre[1] + 3, math.log(MAX_SIGMA_PX), math.log(MAX_SIGMA_PX), math.pi]
    x0 = np.clip(x0, np.array(lower) + 1e-9, np.array(upper) - 1e-9)

    def residuals(params: np.ndarray) -> np.ndarray:
        model = _model(params, px, py)
        return np.where(
            high, np.maximum(0.0, values - model), np.where(low, np.maximum(0.0, model - values), model - values)
        )

    try:
        result = least_squares(residuals, x0, bounds=(lower, upper), x_scale="jac", max_nfev=200)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not result.success:
        return None
    a, b, cx, cy, log_s1, log_s2, theta = result.x
    return DotFit(
        amplitude=float(a),
        background=float(b),
        centre=np.array([cx, cy]),
        cov=covariance(math.exp(log_s1), math.exp(log_s2), theta),
        samples=int(len(values)),
        censored=int((high | low).sum()),
    )


@dataclass
class DotGrid:
    """Dots at ``x = origin_x + i spacing_x``, ``y = origin_y + j spacing_y`` (projector px), ``cols x rows``."""

    spacing_px: tuple[int, int]  # (along y, along x) = (row spacing, column spacing)
    origin_px: tuple[float, float]  # (y, x) of dot (0, 0)
    rows: int
    cols: int

    @classmethod
    def covering(cls, projector_hw: tuple[int, int], spacing_px: tuple[int, int], origin_px=(0, 0)) -> "DotGrid":
        H, W = projector_hw
        sy, sx = spacing_px
        if sy < 4 or sx < 4:
            raise EdofprojError(f"a dot spacing of {sx}x{sy} px leaves the dots' PSFs overlapping (at least 4 px)")
        oy, ox = origin_px
        if not (0 <= oy <= H - 1 and 0 <= ox <= W - 1):
            raise EdofprojError(f"the first dot, origin_px ({oy:g}, {ox:g}) (y, x), is outside the {W}x{H} projector")
        return cls((sy, sx), (float(oy), float(ox)), int((H - 1 - oy) // sy) + 1, int((W - 1 - ox) // sx) + 1)

    @property
    def xs(self) -> np.ndarray:
        return self.origin_px[1] + self.spacing_px[1] * np.arange(self.cols)

    @property
    def ys(self) -> np.ndarray:
        return self.origin_px[0] + self.spacing_px[0] * np.arange(self.rows)


@dataclass
class PSFMap:
    """Anisotropic Gaussian PSFs on a grid of projector points (module docstring): ``cov``
    ``(rows, cols, 2, 2)`` in projector px^2 at ``ys`` x ``xs`` (the dots' nominal positions);
    ``offset_px`` the estimated offset ``o`` ``(x, y)`` of the decoded map: the projector pixel a
    camera pixel sees is ``P(q) - o``; ``fitted`` ``(rows, cols)`` where a dot was fitted;
    ``channel`` the colour the map is for (``mean``: white dots read as the mean of R, G, B;
    ``red``, ``green``, ``blue``: that primary's dots read in the camera's channel of that colour)."""

    xs: np.ndarray
    ys: np.ndarray
    cov: np.ndarray
    offset_px: np.ndarray
    fitted: np.ndarray
    projector_hw: tuple[int, int]
    channel: str = "mean"

    @property
    def sigma_x(self) -> np.ndarray:
        """``(rows, cols)`` marginal width along the projector's x (across columns), px."""
        return np.sqrt(self.cov[..., 0, 0])

    @property
    def sigma_y(self) -> np.ndarray:
        """``(rows, cols)`` marginal width along the projector's y (across rows), px."""
        return np.sqrt(self.cov[..., 1, 1])

    @property
    def angle_deg(self) -> np.ndarray:
        """``(rows, cols)`` angle of the ellipse's major axis from the x axis, degrees in (-90, 90]."""
        c = self.cov
        return np.degrees(0.5 * np.arctan2(2 * c[..., 0, 1], c[..., 0, 0] - c[..., 1, 1]))

    def covariance_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``(..., 2, 2)`` covariance at projector points ``(x, y)``, bilinear between grid points
        (clamped to the grid's edges)."""
        x = np.clip(np.asarray(x, dtype=np.float64), self.xs[0], self.xs[-1])
        y = np.clip(np.asarray(y, dtype=np.float64), self.ys[0], self.ys[-1])
        flat = self.cov.reshape(len(self.ys), len(self.xs), 4)
        interp = RegularGridInterpolator((self.ys, self.xs), flat, method="linear")
        return interp(np.stack([y, x], axis=-1)).reshape(*np.shape(x), 2, 2)

    def save(self, path) -> None:
        """Write this one map (:func:`save_psf_maps`)."""
        save_psf_maps(path, [self])

    @classmethod
    def load(cls, path, channel: str | None = None) -> "PSFMap":
        """The file's first map (``channel`` None), or its map for ``channel`` (one line when it has none)."""
        maps = load_psf_maps(path)
        if channel is None:
            return next(iter(maps.values()))
        if channel not in maps:
            raise EdofprojError(
                f"PSF map '{path}' has no map for channel '{channel}' (it has: {', '.join(maps)}): "
                "fit one with 'edofproj procams psf-map --dots' from that colour's dot capture"
            )
        return maps[channel]


_MAP_KEYS = ("xs", "ys", "cov", "offset_px", "fitted")


def _key(channel_index: int, channel: str, key: str) -> str:
    """The file's key for ``key`` of the ``channel_index``-th map: unprefixed for the first (so a
    reader of single-map files reads it), ``{channel}_{key}`` for the others."""
    return key if channel_index == 0 else f"{channel}_{key}"


def save_psf_maps(path, maps: list[PSFMap]) -> None:
    """Write one or more maps of distinct channels (one projector) to one ``.npz``, atomically, in
    the order ``mean``, ``red``, ``green``, ``blue`` (file format: ``docs/formats.md``)."""
    if not maps:
        raise EdofprojError("no PSF map to write")
    names = [m.channel for m in maps]
    if len(set(names)) != len(names) or any(n not in PSF_MAP_CHANNELS for n in names):
        raise EdofprojError(f"PSF maps of channels {names}: each one of {', '.join(PSF_MAP_CHANNELS)}, once")
    if len({tuple(m.projector_hw) for m in maps}) != 1:
        raise EdofprojError("PSF maps of different projector sizes cannot share one file")
    maps = sorted(maps, key=lambda m: PSF_MAP_CHANNELS.index(m.channel))
    arrays: dict[str, np.ndarray] = {}
    for k, m in enumerate(maps):
        for key in _MAP_KEYS:
            arrays[_key(k, m.channel, key)] = np.asarray(getattr(m, key))
    save_npz_atomic(
        path,
        format=np.array(PSF_MAP_FORMAT),
        projector_hw=np.array(maps[0].projector_hw),
        channels=np.array([m.channel for m in maps]),
        **arrays,
    )


def is_kernel_map_file(path) -> bool:
    """Whether the PSF map file ``path`` is a kernel map (:data:`KERNEL_MAP_FORMAT`), not a Gaussian one."""
    return str(read_arrays(path, what="PSF map").get("format", "")) == KERNEL_MAP_FORMAT


def load_psf_maps(path) -> dict[str, PSFMap]:
    """Every map of a PSF map file, by channel, in file order (a file without ``channels``, as
    written before per-colour maps: one map, ``mean``)."""
    try:
        data = read_tagged_arrays(path, "PSF map", PSF_MAP_FORMAT, ("projector_hw", *_MAP_KEYS),
                                  "make one with 'edofproj procams psf-map'")  # fmt: skip
    except EdofprojError:
        if is_kernel_map_file(path):
            raise EdofprojError(
                f"PSF map '{path}' is a kernel map ('psf-map --model rank-profile'), which has no Gaussian "
                "widths: this needs a Gaussian PSF map ('psf-map' without --model)"
            ) from None
        raise
    source = f"PSF map '{path}'"
    channels = [str(c) for c in np.atleast_1d(data["channels"])] if "channels" in data else ["mean"]
    if not channels or len(set(channels)) != len(channels) or any(c not in PSF_MAP_CHANNELS for c in channels):
        raise EdofprojError(f"{source} lists channels {channels}: each one of {', '.join(PSF_MAP_CHANNELS)}, once")
    hw = data["projector_hw"]
    if hw.shape != (2,) or not np.all(hw >= 2):
        raise EdofprojError(f"{source} has a projector size of {hw.tolist()}")
    maps: dict[str, PSFMap] = {}
    for k, channel in enumerate(channels):
        keys = {key: _key(k, channel, key) for key in _MAP_KEYS}
        missing = [name for name in keys.values() if name not in data]
        if missing:
            raise EdofprojError(f"{source} lacks {', '.join(missing)} (channel '{channel}')")
        where = source if len(channels) == 1 else f"{source} (channel '{channel}')"
        xs, ys, cov = data[keys["xs"]], data[keys["ys"]], data[keys["cov"]]
        if xs.ndim != 1 or ys.ndim != 1 or len(xs) < 2 or len(ys) < 2 or cov.shape != (len(ys), len(xs), 2, 2):
            raise EdofprojError(f"{where} has a covariance of shape {cov.shape} for {len(ys)}x{len(xs)} grid points")
        if not (np.all(np.isfinite(cov)) and np.all(np.diff(xs) > 0) and np.all(np.diff(ys) > 0)):
            raise EdofprojError(f"{where} has non-finite covariances or unsorted grid points")
        if np.any(np.linalg.det(cov) <= 0) or np.any(cov[..., 0, 0] <= 0):
            raise EdofprojError(f"{where} has a covariance that is not positive definite")
        offset, fitted = data[keys["offset_px"]], data[keys["fitted"]]
        if offset.shape != (2,) or not np.all(np.isfinite(offset)) or fitted.shape != cov.shape[:2]:
            raise EdofprojError(f"{where} has an offset of shape {offset.shape} or fitted dots of shape {fitted.shape}")
        maps[channel] = PSFMap(
            xs=xs.astype(np.float64),
            ys=ys.astype(np.float64),
            cov=cov.astype(np.float64),
            offset_px=offset.astype(np.float64),
            fitted=fitted.astype(bool),
            projector_hw=(int(hw[0]), int(hw[1])),
            channel=channel,
        )
    return maps


def psf_maps_for_rgb(maps: dict[str, PSFMap]) -> tuple[PSFMap, PSFMap, PSFMap]:
    """The maps for an image's R, G and B planes: each colour's own map where there is one, else the
    ``mean`` (white-dot) map, else the first map."""
    if not maps:
        raise EdofprojError("no PSF map")
    fallback = maps.get("mean", next(iter(maps.values())))
    return tuple(maps.get(c, fallback) for c in ("red", "green", "blue"))  # type: ignore[return-value]


def _samples_by_dot(
    corr: CorrespondenceMap, grid: DotGrid, offset: np.ndarray, half_window: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Camera pixels within ``half_window`` (projector px, per axis) of a dot at ``d + offset``:
    their flat camera indices sorted by dot, the dot index of each, and the split points."""
    valid = corr.valid
    flat = np.flatnonzero(valid)
    px, py = corr.proj_x.ravel()[flat] - offset[0], corr.proj_y.ravel()[flat] - offset[1]
    i = np.rint((px - grid.origin_px[1]) / grid.spacing_px[1]).astype(np.int64)
    j = np.rint((py - grid.origin_px[0]) / grid.spacing_px[0]).astype(np.int64)
    near = (
        (i >= 0)
        & (i < grid.cols)
        & (j >= 0)
        & (j < grid.rows)
        & (np.abs(px - grid.xs[np.clip(i, 0, grid.cols - 1)]) <= half_window)
        & (np.abs(py - grid.ys[np.clip(j, 0, grid.rows - 1)]) <= half_window)
    )
    flat, dot = flat[near], (j * grid.cols + i)[near]
    order = np.argsort(dot, kind="stable")
    flat, dot = flat[order], dot[order]
    dots, starts = np.unique(dot, return_index=True)
    return flat, dots, starts, np.r_[starts[1:], len(flat)]


def fit_dots(
    capture: np.ndarray,
    high: np.ndarray,
    low: np.ndarray,
    corr: CorrespondenceMap,
    grid: DotGrid,
    offset: np.ndarray,
    half_window: float,
    top: float,
    every: int = 1,
    progress: StageProgress | None = None,
    stage: str = "fitting dots",
) -> dict[int, DotFit]:
    """:func:`fit_dot` for the grid's dots (every ``every``-th in both directions), by dot index
    ``j cols + i``; centres are relative to the nominal dot positions (without ``offset``).
    ``progress``: shows ``stage``, one unit per dot."""
    flat, dots, starts, ends = _samples_by_dot(corr, grid, offset, half_window)
    values, hi, lo = capture.ravel(), high.ravel(), low.ravel()
    px_all, py_all = corr.proj_x.ravel(), corr.proj_y.ravel()
    fits: dict[int, DotFit] = {}
    chosen = [
        (int(d), s, e) for d, s, e in zip(dots, starts, ends) if not (d % grid.cols % every or d // grid.cols % every)
    ]
    if progress is not None:
        progress.start(stage, len(chosen), detail=f"{len(chosen)} dots")
    for dot, start, end in chosen:
        if progress is not None:
            progress.advance()
        j, i = divmod(dot, grid.cols)
        idx = flat[start:end]
        fit = fit_dot(
            px_all[idx] - grid.xs[i],
            py_all[idx] - grid.ys[j],
            values[idx],
            hi[idx],
            lo[idx],
            (float(offset[0]), float(offset[1])),
            top,
        )
        if fit is not None:
            fits[int(dot)] = fit
    if progress is not None:
        progress.finish(f"{len(fits)} of {len(chosen)} fitted")
    return fits


def estimate_offset(fits: dict[int, DotFit]) -> np.ndarray:
    """``o``: the median over dots of the fitted centre minus the nominal dot position ``(x, y)``."""
    if not fits:
        raise EdofprojError("no dot could be fitted: is the dot capture registered with the decoded map?")
    return np.median(np.stack([f.centre for f in fits.values()]), axis=0)


def smooth_covariances(cov: np.ndarray, size: int) -> np.ndarray:
    """``(rows, cols, 2, 2)``: the median over ``size x size`` grid points (NaN where not fitted,
    ignored; NaN where none is) of ``log sigma_x``, ``log sigma_y`` and ``rho = S_xy / (sigma_x
    sigma_y)``, put back together as ``S = [[sx^2, rho sx sy], [rho sx sy, sy^2]]`` (a covariance
    whenever ``|rho| < 1``, unlike the component-wise median of ``S``)."""
    cov = np.asarray(cov, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_sx, log_sy = 0.5 * np.log(cov[..., 0, 0]), 0.5 * np.log(cov[..., 1, 1])
        rho = cov[..., 0, 1] / np.sqrt(cov[..., 0, 0] * cov[..., 1, 1])
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a neighbourhood without any fitted dot
        for field in (log_sx, log_sy, rho):
            out.append(ndimage.generic_filter(field, np.nanmedian, size=int(size), mode="constant", cval=np.nan))
    sx, sy, r = np.exp(out[0]), np.exp(out[1]), np.clip(out[2], -0.99, 0.99)
    smooth = np.empty_like(cov)
    smooth[..., 0, 0], smooth[..., 1, 1] = sx * sx, sy * sy
    smooth[..., 0, 1] = smooth[..., 1, 0] = r * sx * sy
    return smooth


DEFAULT_SMOOTH_PX = 180.0
"""Width (projector px) of the median that smooths the fitted covariances over the grid
(:func:`smooth_covariances`, :func:`smoothing_dots`)."""


def smoothing_dots(smooth_px: float, step_px: float) -> int:
    """The odd number of grid points nearest ``smooth_px / step_px`` (at least 1): the median's width
    on a grid of points ``step_px`` apart."""
    if not (math.isfinite(smooth_px) and smooth_px >= 0):
        raise EdofprojError(f"a smoothing width of {smooth_px} px must be finite and >= 0")
    return max(1, 2 * int(round(0.5 * (smooth_px / step_px - 1))) + 1)


def measure_psf_map(
    capture: np.ndarray,
    corr: CorrespondenceMap,
    grid: DotGrid,
    top: float = 1.0 - 0.5 / 255.0,
    every: int = 1,
    saturated: np.ndarray | None = None,
    clipped: np.ndarray | None = None,
    channel: str = "mean",
    progress: StageProgress | None = None,
    smooth_px: float = DEFAULT_SMOOTH_PX,
) -> tuple[PSFMap, dict[int, DotFit]]:
    """The PSF map from a grey dot capture ``(Hc, Wc)`` (image units) and the map of the same camera
    pose. ``saturated``/``clipped``: the censored samples, bounds at their own values (default: at
    least ``top`` / at most 0); ``channel``: the colour of the dots (:attr:`PSFMap.channel`);
    ``smooth_px``: the width of the median over the map's grid in projector px (:func:`smoothing_dots`
    of the map's grid step, :func:`smooth_covariances`; 0: none); ``progress``: shows the passes."""
    if not corr.is_complete:
        raise EdofprojError("a PSF map needs a decoded map with columns and rows")
    smooth_dots = smoothing_dots(smooth_px, every * min(grid.spacing_px))
    capture = np.asarray(capture, dtype=np.float64)
    if capture.shape != corr.camera_hw:
        raise EdofprojError(f"the dot capture is {capture.shape[1]}x{capture.shape[0]}, the map's camera "
                            f"{corr.camera_hw[1]}x{corr.camera_hw[0]}")  # fmt: skip
    high = capture >= top if saturated is None else np.asarray(saturated, bool)
    low = capture <= 0.5 / 255.0 if clipped is None else np.asarray(clipped, bool)
    half = 0.5 * min(grid.spacing_px)
    coarse = max(1, every * 3)
    first = fit_dots(capture, high, low, corr, grid, np.zeros(2), half, top, every=coarse, progress=progress,
                     stage=f"{channel}: the map's offset (one dot in {coarse} per direction)")  # fmt: skip
    offset = estimate_offset(first)
    fits = fit_dots(capture, high, low, corr, grid, offset, half, top, every=every, progress=progress,
                    stage=f"{channel}: fitting dots")  # fmt: skip
    if not fits:
        raise EdofprojError("no dot could be fitted about the estimated offset")
    offset = estimate_offset(fits)
    cov = np.full((grid.rows, grid.cols, 2, 2), np.nan)
    for dot, fit in fits.items():
        j, i = divmod(dot, grid.cols)
        cov[j, i] = fit.cov
    fitted = np.isfinite(cov[..., 0, 0])
    rows = np.flatnonzero(fitted.any(axis=1))
    cols = np.flatnonzero(fitted.any(axis=0))
    cov, fitted = (
        cov[rows[0] : rows[-1] + 1 : every, cols[0] : cols[-1] + 1 : every],
        fitted[rows[0] : rows[-1] + 1 : every, cols[0] : cols[-1] + 1 : every],
    )
    xs, ys = grid.xs[cols[0] : cols[-1] + 1 : every], grid.ys[rows[0] : rows[-1] + 1 : every]
    if len(xs) < 2 or len(ys) < 2:
        raise EdofprojError(f"dots were fitted on {len(ys)}x{len(xs)} grid points only: at least 2x2 needed")
    smooth = smooth_covariances(cov, smooth_dots)
    missing = ~np.isfinite(smooth[..., 0, 0])
    if missing.any():
        _, (ny, nx) = ndimage.distance_transform_edt(missing, return_indices=True)
        smooth = smooth[ny, nx]
    psf_map = PSFMap(
        xs=xs, ys=ys, cov=smooth, offset_px=offset, fitted=fitted, projector_hw=corr.projector_hw, channel=channel
    )
    return psf_map, fits


def interior_dots(fitted: np.ndarray) -> np.ndarray:
    """``(rows, cols)``: the fitted dots at least two grid steps inside the fitted region (all 24
    neighbours within two steps fitted). A dot at the projection's edge (or the fitted region's, or
    the grid's) sees part of its light fall off the surface or outside the decoded map, and its fit
    widens; near the edge the map's median window is half outside the fitted region and those widths
    weigh more in it. Summaries and colour scales leave both rings out."""
    inner = ndimage.binary_erosion(np.asarray(fitted, bool), structure=np.ones((5, 5), bool), border_value=0)
    return np.asarray(inner & fitted)


def summary(psf_map: PSFMap) -> str:
    """One line: the medians of ``sigma_x``, ``sigma_y`` and the major axis's angle over the interior
    dots (:func:`interior_dots`; all fitted dots when none is interior), and how many were left out."""
    inner = interior_dots(psf_map.fitted)
    fitted = int(psf_map.fitted.sum())
    over = f"over {int(inner.sum())} interior dots ({fitted - int(inner.sum())} at the edge left out)"
    if not inner.any():
        inner, over = psf_map.fitted, f"over all {fitted} fitted dots (none is two dots inside the fitted region)"
    return (
        f"median sigma_x {np.median(psf_map.sigma_x[inner]):.2f} px, sigma_y {np.median(psf_map.sigma_y[inner]):.2f} "
        f"px, major axis at {np.median(psf_map.angle_deg[inner]):.0f} deg, {over}"
    )


def figure_panels(psf_map: PSFMap) -> list[dict]:
    """The figure's three panels: ``values`` ``(rows, cols)``, ``title``, ``cmap``, ``vmin``, ``vmax``.
    The widths share one colour scale, from the 2nd to the 98th percentile of the interior dots'
    widths (:func:`interior_dots`: edge dots' widths are outliers that would set it); the angle, which
    wraps at +-90 deg, uses the cyclic map ``twilight`` over -90..90 deg."""
    inner = interior_dots(psf_map.fitted)
    inner = inner if inner.any() else psf_map.fitted
    if not inner.any():
        inner = np.ones_like(psf_map.fitted)
    widths = np.concatenate([psf_map.sigma_x[inner], psf_map.sigma_y[inner]])
    low, high = (float(v) for v in np.percentile(widths, [2, 98]))
    high = max(high, low + 1e-3)
    return [
        {"values": psf_map.sigma_x, "title": "sigma_x (px)", "cmap": "viridis", "vmin": low, "vmax": high},
        {"values": psf_map.sigma_y, "title": "sigma_y (px)", "cmap": "viridis", "vmin": low, "vmax": high},
        {"values": psf_map.angle_deg, "title": "major axis (deg)", "cmap": "twilight", "vmin": -90.0, "vmax": 90.0},
    ]


def plot_psf_map(psf_map: PSFMap | list[PSFMap], path) -> None:
    """Draw ``sigma_x``, ``sigma_y`` and the major axis's angle over the projector image, a row per
    map (colour) (:func:`figure_panels`; PNG, atomic)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..fileio import atomic_path

    maps = [psf_map] if isinstance(psf_map, PSFMap) else list(psf_map)
    fig, grid = plt.subplots(len(maps), 3, figsize=(13, 4.5 * len(maps)), squeeze=False)
    for axes, m in zip(grid, maps):
        extent = (m.xs[0], m.xs[-1], m.ys[-1], m.ys[0])
        for ax, panel in zip(axes, figure_panels(m)):
            shown = ax.imshow(
                panel["values"], extent=extent, cmap=panel["cmap"], vmin=panel["vmin"], vmax=panel["vmax"]
            )
            ax.set_title(f"{m.channel}: {panel['title']}" if len(maps) > 1 else panel["title"])
            ax.set_xlabel("projector x (px)")
            ax.set_ylabel("projector y (px)")
            fig.colorbar(shown, ax=ax, shrink=0.8, extend="both" if panel["cmap"] != "twilight" else "neither")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=80)
    plt.close(fig)
