"""Per-pixel blur kernels as Li et al. (IEEE TII 2020) estimate them from a dot capture, and their blur.

Their scoring protocol blurs a projector image with one ``(2h + 1) x (2h + 1)`` kernel per projector
pixel (``h = 5``: 11 x 11), built from a capture of single lit pixels every ``s`` px (the dots)
brought into projector space:

1. **The dot capture in projector space** (:func:`capture_to_projector`): the capture minus the
   background capture (8-bit counts, negative differences clipped to 0), each camera pixel written to
   the projector pixel it sees, rounded to the nearest (``ceil(P - o - 1/2)`` per axis, ``o`` the
   decoded map's offset); where several camera pixels see one projector pixel the last in raster
   order wins, where none does the value is 0.
2. **A dot's kernel** (:func:`rank_kernel`): the window of ``(2h + 1)^2`` values around the dot,
   divided by 255, *rearranged by rank*: its distinct values sorted in descending order, the first
   ``n = (h + 1)(h + 2) / 2`` of them (zeros when there are fewer) placed on the kernel's ``n``
   *orbits* -- the sets of offsets ``(+-i, +-j)``, ``(+-j, +-i)`` for ``0 <= j <= i <= h``, taken in
   the order ``(0, 0), (1, 0), (1, 1), (2, 0), ...`` -- then divided by its sum. This is their
   ``scaleGauss``: not a Gaussian fit. The kernel is 8-fold symmetric, its values fall with the
   orbit's order, and its shape depends only on the *number of distinct grey levels* near the
   dot, never on where they are (a dot captured with 21 distinct levels gives a kernel as wide as
   the window, whatever the dot's real width; a saturated core counts as one level).
3. **Between dots** (:func:`kernel_field`): a pixel that is not a dot takes the bilinear combination
   of the four dots around it (``u``, ``v`` its fractional position in the cell), rearranged by rank
   and normalized again. A pixel without four dots around it -- beyond the last row or column of
   dots, including the last row and column of dots themselves -- keeps a zero kernel, and its
   blurred value is 0. A dot whose window is all zero (not seen) keeps a zero kernel.
4. **The blur** (:meth:`LabKernelField.apply`): each output pixel is the sum of its own kernel times
   the input around it (zero outside the image): ``(A x)(p) = sum_d k_p(d) x(p + d)``. Every kernel
   is constant on orbits, so ``A x = sum_k w_k * S_k x`` with ``w_k`` ``(H, W)`` the orbit values and
   ``S_k x = sum_(d in orbit k) x(. + d)``; the adjoint is ``A^T y = sum_k S_k (w_k y)`` (``S_k`` is
   symmetric: each orbit holds ``-d`` with ``d``).

A field is stored as its orbit values ``(n, H, W)`` (21 per pixel instead of 121), which is exact for
every kernel the protocol builds.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..errors import EdofprojError
from ..limits import check_memory
from .psf_map import DotGrid
from .structured_light import CorrespondenceMap

DEFAULT_HALF_PX = 5
"""Half-width of the protocol's windows: 11 x 11 (their ``kernel_radius = 6``)."""
ROWS_PER_CHUNK = 64
"""Projector rows interpolated at a time (memory: ``rows * W * n`` values)."""


@lru_cache(maxsize=8)
def orbits(half_px: int = DEFAULT_HALF_PX) -> tuple[tuple[tuple[int, int], ...], ...]:
    """The orbits' offsets ``(dy, dx)``, in the rank order of the module docstring."""
    out = []
    for i in range(half_px + 1):
        for j in range(i + 1):
            points = {(sy * a, sx * b) for a, b in ((i, j), (j, i)) for sy in (1, -1) for sx in (1, -1)}
            out.append(tuple(sorted(points)))
    return tuple(out)


def orbit_sizes(half_px: int = DEFAULT_HALF_PX) -> np.ndarray:
    """``(n,)`` how many offsets each orbit holds (1, 4 or 8)."""
    return np.array([len(o) for o in orbits(half_px)], dtype=np.float64)


def _orbit_index(half_px: int) -> np.ndarray:
    """``(2h + 1, 2h + 1)`` the orbit of each window position."""
    index = np.empty((2 * half_px + 1, 2 * half_px + 1), dtype=np.int64)
    for k, points in enumerate(orbits(half_px)):
        for dy, dx in points:
            index[half_px + dy, half_px + dx] = k
    return index


def rank_values(values: np.ndarray, n: int) -> np.ndarray:
    """``(N, n)``: for each row of ``values`` ``(N, M)`` (non-negative), its distinct values in
    descending order, the first ``n`` of them, zeros after the last (their ``scaleGauss`` before the
    values are placed on the orbits)."""
    values = np.asarray(values, dtype=np.float64)
    ranked = -np.sort(-values, axis=1)
    repeat = np.zeros(ranked.shape, dtype=bool)
    repeat[:, 1:] = ranked[:, 1:] == ranked[:, :-1]
    ranked[repeat] = -1.0
    ranked = -np.sort(-ranked, axis=1)[:, :n]
    ranked[ranked < 0] = 0.0
    if ranked.shape[1] < n:
        ranked = np.pad(ranked, ((0, 0), (0, n - ranked.shape[1])))
    return ranked


def _normalize(orbit_values: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Each kernel divided by its sum ``sum_k |orbit k| w_k``; a zero kernel stays zero."""
    total = orbit_values @ sizes
    return np.divide(orbit_values, total[:, None], out=np.zeros_like(orbit_values), where=total[:, None] != 0)


def rank_kernel(windows: np.ndarray) -> np.ndarray:
    """``(N, n)`` orbit values of the kernels of ``windows`` ``(N, 2h + 1, 2h + 1)`` (step 2 of the
    module docstring, after the division by 255: their ``scaleGauss`` and the normalization)."""
    windows = np.asarray(windows, dtype=np.float64)
    size = windows.shape[-1]
    if windows.ndim != 3 or windows.shape[1] != size or size % 2 == 0:
        raise EdofprojError(f"kernel windows must be (N, K, K) with K odd, got {windows.shape}")
    half = size // 2
    ranked = rank_values(windows.reshape(len(windows), -1), len(orbits(half)))
    return _normalize(ranked, orbit_sizes(half))


def orbit_window(orbit_values: np.ndarray, half_px: int = DEFAULT_HALF_PX) -> np.ndarray:
    """``(..., 2h + 1, 2h + 1)``: the kernels whose orbit values are ``orbit_values`` ``(..., n)``."""
    return np.asarray(orbit_values)[..., _orbit_index(half_px)]


@dataclass
class LabKernelField:
    """One kernel per projector pixel, as orbit values ``(n, H, W)`` (module docstring)."""

    orbit_values: np.ndarray
    half_px: int = DEFAULT_HALF_PX

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.orbit_values.shape[1]), int(self.orbit_values.shape[2])

    def kernel(self, y: int, x: int) -> np.ndarray:
        """``(2h + 1, 2h + 1)`` the kernel of projector pixel ``(y, x)``."""
        return orbit_window(self.orbit_values[:, y, x], self.half_px)

    def _check(self, image: np.ndarray) -> np.ndarray:
        image = np.asarray(image, dtype=np.float64)
        if image.shape != self.shape:
            raise EdofprojError(
                f"the image is {image.shape[1]}x{image.shape[0]}, the kernels' {self.shape[1]}x{self.shape[0]}"
            )
        return image

    def _pairs(self) -> list[tuple[int, int, int]]:
        """``(i, j, k)`` for every ordered pair ``0 <= i, j <= h``: orbit ``k`` holds the offsets ``(+-i, +-j)``."""
        h = self.half_px
        index = {pair: k for k, pair in enumerate((a, b) for a in range(h + 1) for b in range(a + 1))}
        return [(i, j, index[max(i, j), min(i, j)]) for i in range(h + 1) for j in range(h + 1)]

    def _along(self, padded: np.ndarray, i: int, axis: int) -> np.ndarray:
        """``x(. + i) + x(. - i)`` along ``axis`` (``x`` itself for ``i = 0``) of an array zero-padded by
        ``h`` along it, cut to the image's length there."""
        h, n = self.half_px, self.shape[axis]
        take = [slice(None), slice(None)]
        take[axis] = slice(h + i, h + i + n)
        out = padded[tuple(take)].copy()
        if i:
            take[axis] = slice(h - i, h - i + n)
            out += padded[tuple(take)]
        return out

    def apply(self, image: np.ndarray) -> np.ndarray:
        """``A x`` of a ``(H, W)`` image: each pixel its own kernel times its neighbourhood. An orbit's
        offsets are ``(+-i, +-j)`` and ``(+-j, +-i)``, so ``S_k = C_j R_i + C_i R_j`` (``R_i``, ``C_j`` the
        symmetric shifts along columns and rows; one term when ``i = j``), and the ``R_i x`` are shared.
        Computed in the dtype of the orbit values."""
        dtype = self.orbit_values.dtype
        padded = np.pad(self._check(image).astype(dtype, copy=False), self.half_px)
        rows = [self._along(padded, i, 0) for i in range(self.half_px + 1)]  # (H, W + 2h) each
        out = np.zeros(self.shape, dtype)
        for i, j, k in self._pairs():
            term = self._along(rows[i], j, 1)
            term *= self.orbit_values[k]
            out += term
        return out

    def adjoint(self, image: np.ndarray) -> np.ndarray:
        """``A^T y = sum_k S_k (w_k y)`` of a ``(H, W)`` image (``<A x, y> = <x, A^T y>``)."""
        dtype = self.orbit_values.dtype
        image = self._check(image).astype(dtype, copy=False)
        out = np.zeros(self.shape, dtype)
        weighted: dict[int, np.ndarray] = {}
        for i, j, k in sorted(self._pairs(), key=lambda pair: pair[2]):
            if k not in weighted:
                weighted = {k: np.pad(self.orbit_values[k] * image, self.half_px)}
            out += self._along(self._along(weighted[k], i, 0), j, 1)
        return out

    def astype(self, dtype) -> "LabKernelField":
        """The same kernels in another floating dtype (``float32``: half the memory and time)."""
        return LabKernelField(self.orbit_values.astype(dtype), self.half_px)

    def norm_bound(self) -> float:
        """An upper bound of ``||A||_2``: ``sqrt(||A||_1 ||A||_inf)``, the largest column sum (``A^T 1``)
        times the largest row sum (``A 1``; 1 for normalized kernels) of the non-negative ``A``."""
        ones = np.ones(self.shape)
        return float(np.sqrt(self.adjoint(ones).max() * self.apply(ones).max()))


def dot_windows(image: np.ndarray, ys: np.ndarray, xs: np.ndarray, half_px: int = DEFAULT_HALF_PX) -> np.ndarray:
    """``(rows, cols, 2h + 1, 2h + 1)``: the window around every dot at integer rows ``ys`` x columns ``xs``
    of a projector-space image ``(H, W)`` (zero outside it)."""
    padded = np.pad(np.asarray(image, dtype=np.float64), half_px)
    ys, xs = np.asarray(ys, dtype=np.int64), np.asarray(xs, dtype=np.int64)
    offsets = np.arange(2 * half_px + 1)
    return padded[ys[:, None, None, None] + offsets[None, None, :, None], xs[None, :, None, None] + offsets]


def kernel_field(dot_image: np.ndarray, grid: DotGrid, half_px: int = DEFAULT_HALF_PX) -> LabKernelField:
    """Their kernel at every pixel (steps 2-3 of the module docstring) from the dot capture in projector
    space ``dot_image`` ``(H, W)`` (background subtracted, in 8-bit counts) and the dots' grid (integer
    positions)."""
    image = np.asarray(dot_image, dtype=np.float64) / 255.0
    if image.ndim != 2:
        raise EdofprojError(f"the dot image must be (H, W), got {image.shape}")
    H, W = image.shape
    oy, ox = grid.origin_px
    if oy != int(oy) or ox != int(ox) or oy < 0 or ox < 0:
        raise EdofprojError(
            f"the protocol's kernels need dots on whole pixels from the image's corner, not {grid.origin_px}"
        )
    n = len(orbits(half_px))
    check_memory(3 * H * W * n * 8, "the protocol's per-pixel kernels", "a smaller projector image")
    ys, xs = grid.ys.astype(np.int64), grid.xs.astype(np.int64)
    ys, xs = ys[ys < H], xs[xs < W]
    if len(ys) < 2 or len(xs) < 2:
        raise EdofprojError(f"the dot grid has {len(ys)}x{len(xs)} dots in the image: at least 2x2 needed")
    windows = dot_windows(image, ys, xs, half_px)
    dots = rank_kernel(windows.reshape(-1, 2 * half_px + 1, 2 * half_px + 1)).reshape(len(ys), len(xs), n)

    values = np.zeros((H, W, n))
    sizes = orbit_sizes(half_px)
    sy, sx = grid.spacing_px
    cols = np.arange(W)
    ci = (cols - xs[0]) // sx
    inside_x = (cols >= xs[0]) & (ci + 1 < len(xs))
    ci = np.clip(ci, 0, len(xs) - 2)
    v = (cols - xs[ci]) / sx
    for start in range(0, H, ROWS_PER_CHUNK):
        rows = np.arange(start, min(start + ROWS_PER_CHUNK, H))
        rj = (rows - ys[0]) // sy
        inside_y = (rows >= ys[0]) & (rj + 1 < len(ys))
        rj = np.clip(rj, 0, len(ys) - 2)
        u = ((rows - ys[rj]) / sy)[:, None, None]
        vv = v[None, :, None]
        block = (
            (1 - u) * (1 - vv) * dots[rj][:, ci]
            + (1 - u) * vv * dots[rj][:, ci + 1]
            + u * (1 - vv) * dots[rj + 1][:, ci]
            + u * vv * dots[rj + 1][:, ci + 1]
        )
        block = _normalize(rank_values(block.reshape(-1, n), n), sizes).reshape(len(rows), W, n)
        block[~(inside_y[:, None] & inside_x[None, :])] = 0.0
        values[rows] = block
    values[np.ix_(ys, xs)] = dots
    return LabKernelField(np.ascontiguousarray(np.moveaxis(values, -1, 0)), half_px)


def capture_to_projector(
    capture: np.ndarray,
    corr: CorrespondenceMap,
    offset_px: tuple[float, float] = (0.0, 0.0),
    background: np.ndarray | None = None,
) -> np.ndarray:
    """``(H, W, C)``: a capture ``(Hc, Wc, C)`` in 8-bit counts, less ``background`` (clipped at 0),
    at the projector pixel each camera pixel sees (step 1 of the module docstring), 0 where none."""
    capture = np.asarray(capture, dtype=np.float64)
    if capture.ndim == 2:
        capture = capture[..., None]
    if capture.shape[:2] != corr.camera_hw:
        raise EdofprojError(
            f"the capture is {capture.shape[1]}x{capture.shape[0]}, the map's camera {corr.camera_hw[1]}x{corr.camera_hw[0]}"
        )
    if background is not None:
        background = np.asarray(background, dtype=np.float64).reshape(capture.shape)
        capture = np.maximum(capture - background, 0.0)
    if not corr.is_complete:
        raise EdofprojError("the protocol's kernels need a decoded map with columns and rows")
    H, W = corr.projector_hw
    valid = corr.valid
    with np.errstate(invalid="ignore"):
        col = np.ceil(corr.proj_x - offset_px[0] - 0.5)
        row = np.ceil(corr.proj_y - offset_px[1] - 0.5)
        valid = valid & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    flat = np.flatnonzero(valid)
    target = row.ravel()[flat].astype(np.int64) * W + col.ravel()[flat].astype(np.int64)
    # the last camera pixel in raster order wins: first occurrence in the reversed order
    last_target, first_in_reversed = np.unique(target[::-1], return_index=True)
    source = flat[::-1][first_in_reversed]
    out = np.zeros((H * W, capture.shape[-1]))
    out[last_target] = capture.reshape(-1, capture.shape[-1])[source]
    return out.reshape(H, W, capture.shape[-1])
