"""Projection with a PSF that varies across the image (field-dependent PSFs).

A projector pixel at ``x'`` sends its light through the lens at its own field angle, so its
PSF ``p(.; x')`` depends on where the pixel sits. Given PSFs ``p_g`` at a regular grid of
field points (pixel centres ``(cy_i, cx_j)``), the PSF of a source pixel is their bilinear
interpolation,

    p(.; x') = sum_g w_g(x') p_g,     w_g(x') = hat_i(y') hat_j(x'),

with ``hat`` the piecewise-linear interpolation weights along each axis (constant beyond the
outermost centres; ``sum_g w_g = 1``). The screen shows

    out(y) = sum_{x'} I(x') p(y - x'; x') = sum_g ( (w_g I) (*) p_g )(y)
             + sum_g (1 - sum p_g) mean(w_g I)                        (haze, per channel)

-- exactly: one 'same' FFT convolution (:func:`edofproj.imaging.convolution.convolve_same`)
per grid PSF, the image weighted by ``w_g`` first. Interpolating the *sources'* PSFs (not the
outputs) keeps the energy: every source pixel's light sums to its own interpolated in-window
energy plus haze, and with every ``p_g`` equal this is :func:`edofproj.imaging.project`.

:class:`FieldVaryingBlur` is this operator without clamp and haze, and its exact adjoint, in a low-rank form:
the node kernels written in an orthonormal basis ``e_m``, ``A x = sum_m e_m (*) (c_m . x)`` with smooth
coefficient maps ``c_m``, ``M`` convolutions of the image. **Tiled form**: ``A`` is linear in the sources, so
the image is cut into source tiles ``T_t`` and ``A x = sum_t A (1_t . x)``; a tile's sources use only the
kernels of the nodes whose tent weights reach it, which span fewer directions than all of them, so each tile
gets its own basis ``e_tm`` (``M_t`` terms) and its light, the tile grown by ``K // 2``, is convolved on the
tile's own FFT grid ('full' linear convolution) and added into the image: exact for the (truncated) node
kernels, ``sum_t (M_t + 1)`` transforms of tile-sized grids per application instead of ``M + 1`` of the
image's; the tiling is chosen by the FFT work it costs (:class:`FieldVaryingBlur`).

Shapes: image ``(B, C, H, W)``; ``psf_grid`` ``(Gy, Gx, C or 1, K, K)``; centres in pixels
(``(Gy,)`` rows, ``(Gx,)`` columns, increasing). :func:`field_centres_px` maps normalized
field coordinates in [-1, 1] (the image edges) to pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
import torch

from ..errors import EdofprojError
from .convolution import convolve_same, fast_fft_length, optical_transfer_function

BATCH_ELEMENTS = 1 << 23
"""Real samples (frames x padded pixels) :class:`FieldVaryingBlur` transforms in one batched FFT call on the CPU:
32 MiB in float32, the largest block the C library's allocator reuses instead of mapping fresh pages (whose
faults cost as much system time as the transforms)."""


def field_centres_px(field_coords, size_px: int) -> np.ndarray:
    """Pixel coordinates of normalized field coordinates: -1 is the outer edge of the first
    pixel (-0.5), +1 that of the last (``size_px - 0.5``)."""
    f = np.asarray(field_coords, dtype=float)
    return (f + 1.0) / 2.0 * size_px - 0.5


def hat_weights(centres_px, size_px: int) -> np.ndarray:
    """``(G, size_px)`` piecewise-linear interpolation weights of pixels ``0..size_px-1`` on the
    nodes ``centres_px`` (increasing); constant beyond the ends; columns sum to 1."""
    c = np.asarray(centres_px, dtype=float)
    if c.ndim != 1 or c.size < 1 or np.any(np.diff(c) <= 0):
        raise EdofprojError(f"field-point centres must be a strictly increasing list, got {c.tolist()}")
    pos = np.arange(size_px, dtype=float)
    weights = np.empty((c.size, size_px))
    for g in range(c.size):
        unit = np.zeros(c.size)
        unit[g] = 1.0
        weights[g] = np.interp(pos, c, unit)
    return weights


def project_field_varying(
    image: torch.Tensor, psf_grid: torch.Tensor, centres_y_px, centres_x_px, haze: bool = True
) -> torch.Tensor:
    """What a screen shows when each source pixel has its own (interpolated) PSF (module docstring).

    ``image (B, C, H, W)`` (clamped to [0, 1] as in :func:`edofproj.imaging.project`),
    ``psf_grid (Gy, Gx, C or 1, K, K)``; returns ``(B, C, H, W)``, differentiable in both.
    """
    if image.ndim != 4:
        raise EdofprojError(f"images must be (B, C, H, W), got shape {tuple(image.shape)}")
    if psf_grid.ndim != 5 or psf_grid.shape[-1] != psf_grid.shape[-2] or psf_grid.shape[2] not in (1, image.shape[1]):
        raise EdofprojError(
            f"a PSF grid must be (Gy, Gx, {image.shape[1]} or 1, K, K), got shape {tuple(psf_grid.shape)}"
        )
    Gy, Gx = psf_grid.shape[:2]
    if len(centres_y_px) != Gy or len(centres_x_px) != Gx:
        raise EdofprojError(f"{Gy} x {Gx} grid PSFs but {len(centres_y_px)} x {len(centres_x_px)} centres")
    H, W = image.shape[-2:]
    wy = torch.as_tensor(hat_weights(centres_y_px, H), dtype=image.dtype, device=image.device)
    wx = torch.as_tensor(hat_weights(centres_x_px, W), dtype=image.dtype, device=image.device)
    clamped = image.clamp(0.0, 1.0)
    m = psf_grid.shape[-1] // 2
    kernels = psf_grid.to(dtype=image.dtype, device=image.device)
    out = torch.zeros_like(clamped)
    lost_mean = torch.zeros(clamped.shape[:2] + (1, 1), dtype=image.dtype, device=image.device)
    for i in range(Gy):
        rows = torch.nonzero(wy[i] > 0).flatten()
        for j in range(Gx):
            cols = torch.nonzero(wx[j] > 0).flatten()
            if rows.numel() == 0 or cols.numel() == 0:
                continue
            # the weight's support grown by the kernel radius: the light of w_g I stays inside it
            y0, y1 = max(int(rows[0]) - m, 0), min(int(rows[-1]) + m + 1, H)
            x0, x1 = max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, W)
            weight = wy[i, y0:y1, None] * wx[j, None, x0:x1]
            weighted = clamped[..., y0:y1, x0:x1] * weight
            kernel = kernels[i, j][None]  # (1, C, K, K)
            out[..., y0:y1, x0:x1] += convolve_same(weighted, kernel)
            if haze:
                lost = 1.0 - kernel.sum(dim=(-1, -2), keepdim=True)
                lost_mean = lost_mean + lost * weighted.sum(dim=(-1, -2), keepdim=True) / (H * W)
    return out + lost_mean if haze else out


def low_rank_kernels(
    kernels: torch.Tensor, tolerance: float = 0.0, sketches: tuple[int, ...] = (32, 64), gram: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """``kernels (N, Kh, Kw) ~= sum_m coefficients[:, m] basis[m]``: the truncated singular value
    decomposition of the ``N x Kh Kw`` matrix ``X`` of the kernels, keeping the fewest ``M`` components whose
    dropped singular values ``sigma_m`` satisfy ``sqrt(sum_dropped sigma_m^2) <= tolerance * ||X||_F``
    (``tolerance = 0``: all above ``1e-12 sigma_0``, exact to rounding). Returns ``basis (M, K, K)`` (orthonormal)
    and ``coefficients (N, M)`` float64. With more kernels than taps (``N > K^2``) the right singular
    vectors are the eigenvectors of ``X^T X`` (a ``K^2 x K^2`` problem, whatever ``N``). Many large kernels
    with a tolerance: the randomized basis of :func:`_randomized_low_rank`, sketches of ``sketches`` vectors
    tried in turn (the first that reaches the tolerance), the exact decomposition if none does. ``gram`` (with a
    tolerance): the eigenvectors of the smaller Gram matrix (``X X^T`` or ``X^T X``) whatever the size, the
    same truncation to rounding of order ``1e-8 sigma_0`` (far below any tolerance) in a tenth of the time of
    the SVD for a few hundred kernels."""
    n, (kh, kw) = kernels.shape[0], kernels.shape[-2:]
    taps = kh * kw
    matrix = kernels.reshape(n, taps).to(torch.float64)
    gram = gram and float(tolerance) > 0
    if float(tolerance) > 0 and n * taps > 4_000_000 and not gram:
        for most in sketches:
            sketched = _randomized_low_rank(matrix, float(tolerance), most)
            if sketched is not None:
                return sketched.T.reshape(sketched.shape[1], kh, kw), matrix @ sketched
    if n * taps <= 4_000_000 and not gram:
        _, sigma, vh = torch.linalg.svd(matrix, full_matrices=False)
        energy, vectors = sigma**2, vh.T
    elif n > taps:  # the right singular vectors: eigenvectors of X^T X
        energy, vectors = torch.linalg.eigh(matrix.T @ matrix)
        energy, vectors = torch.flip(energy, (0,)).clamp_min(0.0), torch.flip(vectors, (1,))
    else:  # the left ones, eigenvectors of X X^T; v_m = X^T u_m / sigma_m
        energy, left = torch.linalg.eigh(matrix @ matrix.T)
        energy, left = torch.flip(energy, (0,)).clamp_min(0.0), torch.flip(left, (1,))
        keep = energy > 1e-14 * energy[0]  # the Gram matrix's rounding: smaller ones are noise
        energy, left = energy[keep], left[:, keep]
        vectors = (matrix.T @ left) / torch.sqrt(energy)
    rank = _kept_terms(energy, float(tolerance))
    basis = vectors[:, :rank]
    return basis.T.reshape(rank, kh, kw), matrix @ basis


def _kept_terms(energy: torch.Tensor, tolerance: float) -> int:
    """The fewest terms of :func:`low_rank_kernels` for the squared singular values ``energy`` (decreasing):
    the numerical rank (``sigma > 1e-12 sigma_0``) without a tolerance, else the fewest whose dropped energy
    is at most ``tolerance^2`` of the total."""
    if tolerance <= 0:
        return max(int((energy > 1e-24 * energy[0]).sum()), 1)
    dropped = torch.flip(torch.cumsum(torch.flip(energy, (0,)), 0), (0,))  # dropped[m]: energy beyond m terms
    bound = tolerance**2 * float(energy.sum())
    return next((m for m in range(1, len(energy)) if float(dropped[m]) <= bound), len(energy))


def _randomized_low_rank(matrix: torch.Tensor, tolerance: float, most: int = 64) -> torch.Tensor | None:
    """Orthonormal right vectors ``V (taps, M)`` of a large ``matrix`` whose projection keeps it within
    ``tolerance`` (relative Frobenius), by the randomized SVD (:func:`torch.svd_lowrank`, at most
    ``most`` vectors); None when ``most`` do not reach it. The error is computed exactly,
    ``||X - X V V^T||^2 = ||X||^2 - ||X V||^2``, not estimated."""
    generator_state = torch.random.get_rng_state()
    torch.manual_seed(0)  # the same basis for the same kernels, run after run
    try:
        _, _, v = torch.svd_lowrank(matrix, q=min(most, *matrix.shape), niter=4)
    finally:
        torch.random.set_rng_state(generator_state)
    kept = torch.cumsum(((matrix @ v) ** 2).sum(dim=0), 0)
    total = float((matrix**2).sum())
    enough = torch.nonzero(total - kept <= tolerance**2 * total).flatten()
    return None if enough.numel() == 0 else v[:, : int(enough[0]) + 1]


MIN_TILE_KERNELS = 4
"""Least side of an automatically chosen source tile, in kernel widths ``K``: a smaller tile's frame would be
mostly the ``K - 1`` pixels of margin its 'full' convolution needs."""
RANK_ESTIMATE_NODES = 256
"""Most node kernels a tile's rank is estimated from when :class:`FieldVaryingBlur` chooses its tiling."""
TILE_CANDIDATES = (1, 2, 3, 4, 6, 8)
"""Row bands of the tilings :class:`FieldVaryingBlur` weighs (columns: as many bands as keep tiles about
square), each kept only when its tiles are at least :data:`MIN_TILE_KERNELS` kernels wide."""


@dataclass
class SourceTile:
    """One source tile of :class:`FieldVaryingBlur`: the sources ``rows x cols`` (half-open pixel ranges), the
    region ``out_rows x out_cols`` their light reaches (grown by ``K // 2``, clipped to the image), the tile's
    position ``offset`` inside that region, the FFT ``grid``, the tile's orthonormal ``basis (C|1, M_t, K, K)``
    and its coefficient maps ``coefficients (C|1, M_t, th, tw)`` (float64)."""

    rows: tuple[int, int]
    cols: tuple[int, int]
    out_rows: tuple[int, int]
    out_cols: tuple[int, int]
    grid: tuple[int, int]
    basis: torch.Tensor
    coefficients: torch.Tensor

    @property
    def offset(self) -> tuple[int, int]:
        return (self.rows[0] - self.out_rows[0], self.cols[0] - self.out_cols[0])

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows[1] - self.rows[0], self.cols[1] - self.cols[0])

    @property
    def rank(self) -> int:
        return int(self.basis.shape[1])


def tile_grid(rows: tuple[int, int], cols: tuple[int, int], size_hw: tuple[int, int], k: int) -> tuple[int, int]:
    """The FFT grid of a source tile ``rows x cols`` of an image of ``size_hw`` under ``K x K`` kernels.

    Along one axis, with tile length ``n``, ``a, b <= K // 2 = r`` the margins kept above and below it (the
    output region ``a + n + b`` long), the tile placed at ``a`` and the kernel centred at ``0``: its light lands
    at ``[a - r, a + n + r)``; the circular convolution is linear on ``[0, a + n + b)`` when the light below
    ``0`` wraps past the region (``G >= n + r + b``) and none beyond it wraps into it (``G >= a + n + r``):
    ``G >= max(n + r + max(a, b), K)``, the next fast length. The whole image (``a = b = 0``) gives
    :func:`.convolution.fft_shape`; an inner tile the 'full' convolution ``n + K - 1``."""
    r = k // 2
    lengths = []
    for (first, last), size in zip((rows, cols), size_hw):
        before, after = min(first, r), min(size - last, r)
        lengths.append(fast_fft_length(max(last - first + r + max(before, after), k)))
    return (lengths[0], lengths[1])


def _bands(size: int, count: int) -> list[tuple[int, int]]:
    """``count`` contiguous pixel ranges covering ``0..size``, lengths differing by at most one."""
    edges = np.linspace(0, size, count + 1).round().astype(int)
    return [(int(edges[i]), int(edges[i + 1])) for i in range(count)]


class FieldVaryingBlur:
    """The linear blur whose PSF varies across the image, and its exact adjoint.

    Kernels ``h_g`` (``K x K``, odd, centred) are given at a grid of nodes ``g = (i, j)`` at pixel rows
    ``centres_y_px[i]`` and columns ``centres_x_px[j]``; a pixel's PSF is the bilinear interpolation of
    the kernels of the nodes around it, with the tent weights ``w_g`` of :func:`hat_weights`
    (``sum_g w_g = 1``, constant beyond the outermost nodes). The operator is the *source* form

        A x = sum_g h_g (*) (w_g . x),        A^T y = sum_g w_g . (h_g (x) y)

    (``(*)`` the zero-padded 'same' convolution of :mod:`.convolution`, ``(x)`` the correlation,
    ``.`` the pixel-wise product): light leaving pixel ``x'`` spreads with the PSF interpolated at
    ``x'``, so every source's light sums to its own kernel's mass, as a projector pixel's light goes
    through its own PSF. This is :func:`project_field_varying` without its clamp and haze. The other
    order, ``sum_g w_g . (h_g (*) x)``, interpolates the outputs: the adjoint's structure, and how the
    field-varying Wiener filter (:mod:`edofproj.compensation.field_varying`) blends its nodes. Light
    that leaves the image is lost, and none comes from outside it.

    **Computation (low rank).** With the kernels written in an orthonormal basis,
    ``h_g = sum_m a_gm e_m`` (:func:`low_rank_kernels`), the sum over nodes regroups exactly as

        A x = sum_m e_m (*) (c_m . x),        c_m = sum_g a_gm w_g,

    ``M`` convolutions of the whole image by FFT (transfer functions from
    :func:`.convolution.optical_transfer_function` on the :func:`.convolution.fft_shape` grid), ``M``
    forward transforms and one inverse for ``A``, one forward and ``M`` inverse for ``A^T``, however many
    nodes there are.

    **Tiled form.** ``A`` is linear in ``x``: with the image cut into source tiles ``T_t`` (``Ty`` bands of
    rows times ``Tx`` of columns, :class:`SourceTile`), ``A x = sum_t A (1_t . x)``, and the sources of tile
    ``t`` use only the kernels of the nodes ``g`` whose tent weights are non-zero on ``T_t``. Each tile gets the
    orthonormal basis of those kernels alone, ``h_g = sum_m a_tgm e_tm``, ``M_t`` terms, and

        A x = sum_t P_t sum_m e_tm (*) (c_tm . x|T_t),          c_tm = sum_g a_tgm w_g   on T_t,
        (A^T y)|T_t = sum_m c_tm . (e_tm (x) P_t^T y),

    ``P_t`` adding the tile's light into the image on ``T_t`` grown by ``K // 2`` on every side (clipped to the
    image), computed on the tile's own grid (:func:`tile_grid`: the 'full' linear convolution, no
    wrap-around): exact for the (truncated) node kernels, the adjoint its exact transpose. Nearby nodes'
    kernels span fewer directions than all of them (a PSF map of a 1140 x 912 projector: 9 globally, 3 to 6
    per tile of a 3 x 3 tiling), so the tiles' transforms, ``sum_t (M_t + 1)`` of about ``1 / (Ty Tx)`` of
    the image's area, cost less than the ``M + 1`` of the whole image. ``tiles=None`` chooses the tiling with
    the least ``sum_t (M_t + 1) |G_t| log2 |G_t|`` (``|G_t|`` the tile's grid area, ``M_t`` estimated by
    :meth:`_estimated_rank`, then computed only for the chosen tiling) among ``(1, 1)`` and the
    near-square tilings of :data:`TILE_CANDIDATES` whose tiles are at least :data:`MIN_TILE_KERNELS` ``K``
    wide; ``tiles=(Ty, Tx)`` forces one, ``(1, 1)`` the single whole-image basis above.

    ``M_t`` is the tile's kernels' rank (exact: ``rank_tolerance = 0``) or the fewest basis kernels within
    ``rank_tolerance`` (relative Frobenius error of the tile's node kernels together, per channel); the
    truncated operator is the one applied, and its adjoint is exact for it. :attr:`rank` is the largest
    ``M_t``, :attr:`convolutions` their sum (the convolutions, of tiles, per application).

    Shapes: ``kernels (Gy, Gx, C or 1, K, K)`` (a kernel channel axis of 1 serves every colour);
    images ``(B, C, H, W)`` of ``image_hw``, any floating dtype (cached per dtype and device).
    """

    def __init__(
        self,
        kernels: torch.Tensor,
        centres_y_px,
        centres_x_px,
        image_hw: tuple[int, int],
        rank_tolerance: float = 0.0,
        tiles: tuple[int, int] | None = None,
    ):
        kernels = torch.as_tensor(kernels)
        if kernels.ndim != 5 or kernels.shape[-1] != kernels.shape[-2] or kernels.shape[-1] % 2 == 0:
            raise EdofprojError(f"node kernels must be (Gy, Gx, C or 1, K, K) with K odd, got {tuple(kernels.shape)}")
        if not torch.isfinite(kernels).all():
            raise EdofprojError("the node kernels contain NaN or infinite values")
        gy, gx = kernels.shape[0], kernels.shape[1]
        if len(centres_y_px) != gy or len(centres_x_px) != gx:
            raise EdofprojError(f"{gy} x {gx} node kernels but {len(centres_y_px)} x {len(centres_x_px)} centres")
        if not (0.0 <= float(rank_tolerance) < 1.0):
            raise EdofprojError(f"rank tolerance {rank_tolerance} must be in [0, 1)")
        self.height, self.width = int(image_hw[0]), int(image_hw[1])
        if tiles is not None:
            if len(tiles) != 2 or not all(1 <= int(t) <= s for t, s in zip(tiles, (self.height, self.width))):
                raise EdofprojError(
                    f"tiles must be (rows, columns) of bands, 1 to {self.height} x {self.width}, got {tiles}"
                )
            tiles = (int(tiles[0]), int(tiles[1]))
        self.kernels = kernels
        self.rank_tolerance = float(rank_tolerance)
        self.centres_y_px = np.asarray(centres_y_px, dtype=np.float64)
        self.centres_x_px = np.asarray(centres_x_px, dtype=np.float64)
        self._wy = hat_weights(centres_y_px, self.height)  # (Gy, H)
        self._wx = hat_weights(centres_x_px, self.width)  # (Gx, W)
        if tiles is None:
            candidates = self._candidates()
            tiles = candidates[0] if len(candidates) == 1 else min(candidates, key=self._cost)
        #: ``(Ty, Tx)`` the bands of rows and columns of the source tiles.
        self.tiles = tiles
        #: The source tiles, row-major (:class:`SourceTile`).
        self.source_tiles = [self._tile(rows, cols) for rows in _bands(self.height, tiles[0])
                             for cols in _bands(self.width, tiles[1])]  # fmt: skip
        self._cache: dict[tuple, list[tuple[torch.Tensor, torch.Tensor]]] = {}
        self._conjugates: dict[tuple, list[torch.Tensor]] = {}
        self._buffer: tuple[tuple, torch.Tensor] | None = None
        self._norm_bound: torch.Tensor | None = None

    def _nodes(self, rows: tuple[int, int], cols: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Node rows and columns whose tent weights are non-zero on the tile ``rows x cols``."""
        node_rows = np.nonzero((self._wy[:, rows[0] : rows[1]] > 0).any(axis=1))[0]
        node_cols = np.nonzero((self._wx[:, cols[0] : cols[1]] > 0).any(axis=1))[0]
        return node_rows, node_cols

    def _low_rank(
        self, node_rows: np.ndarray, node_cols: np.ndarray, whole: bool
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per kernel channel, :func:`low_rank_kernels` of the nodes ``node_rows x node_cols``; a tile of several
        (``whole`` False) by the Gram matrix when there is a tolerance."""
        block = self.kernels[node_rows][:, node_cols]  # (ni, nj, C|1, K, K)
        k = block.shape[-1]
        return [
            low_rank_kernels(block[:, :, c].reshape(-1, k, k), self.rank_tolerance, gram=not whole)
            for c in range(block.shape[2])
        ]

    def _candidates(self) -> list[tuple[int, int]]:
        """``(1, 1)`` and the near-square tilings of :data:`TILE_CANDIDATES` with tiles ``>= MIN_TILE_KERNELS K``."""
        least = MIN_TILE_KERNELS * int(self.kernels.shape[-1])
        found = [(1, 1)]
        for ty in TILE_CANDIDATES:
            tx = max(1, round(ty * self.width / self.height))
            if (ty, tx) not in found and self.height // ty >= least and self.width // tx >= least:
                found.append((ty, tx))
        return found

    def _estimated_rank(self, rows: tuple[int, int], cols: tuple[int, int]) -> int:
        """An estimate of the rank ``M_t`` of the tile ``rows x cols`` for the choice of a tiling: from the
        eigenvalues alone of the smaller Gram matrix of its kernels, the nodes thinned to every ``s``-th row and
        column when there are more than :data:`RANK_ESTIMATE_NODES` (neighbouring kernels are nearly
        combinations of each other: their rank barely grows with their number, the Gram matrix's cost as its
        cube); without a tolerance, the eigenvalues above ``1e-14`` of the largest (the Gram matrix's rounding)."""
        node_rows, node_cols = self._nodes(rows, cols)
        step = int(np.ceil(np.sqrt(len(node_rows) * len(node_cols) / RANK_ESTIMATE_NODES)))
        node_rows, node_cols = node_rows[::step], node_cols[::step]
        k = int(self.kernels.shape[-1])
        block = self.kernels[node_rows][:, node_cols].to(torch.float64)  # (ni, nj, C|1, K, K)
        ranks = []
        for c in range(block.shape[2]):
            matrix = block[:, :, c].reshape(-1, k * k)
            gram = matrix @ matrix.T if matrix.shape[0] <= matrix.shape[1] else matrix.T @ matrix
            energy = torch.flip(torch.linalg.eigvalsh(gram), (0,)).clamp_min(0.0)
            if self.rank_tolerance > 0:
                ranks.append(_kept_terms(energy, self.rank_tolerance))
            else:
                ranks.append(max(int((energy > 1e-14 * energy[0]).sum()), 1))
        return max(ranks)

    def _cost(self, tiles: tuple[int, int]) -> float:
        """``sum_t (M_t + 1) |G_t| log2 |G_t|``: the FFT work of one application of the tiling ``tiles``."""
        k = int(self.kernels.shape[-1])
        total = 0.0
        for rows in _bands(self.height, tiles[0]):
            for cols in _bands(self.width, tiles[1]):
                rank = self._estimated_rank(rows, cols)
                grid = tile_grid(rows, cols, (self.height, self.width), k)
                total += (rank + 1) * grid[0] * grid[1] * np.log2(grid[0] * grid[1])
        return total

    def _tile(self, rows: tuple[int, int], cols: tuple[int, int]) -> SourceTile:
        node_rows, node_cols = self._nodes(rows, cols)
        k = int(self.kernels.shape[-1])
        wy = torch.as_tensor(self._wy[node_rows, rows[0] : rows[1]])  # (ni, th)
        wx = torch.as_tensor(self._wx[node_cols, cols[0] : cols[1]])  # (nj, tw)
        parts = self._low_rank(node_rows, node_cols, whole=(rows, cols) == ((0, self.height), (0, self.width)))
        rank = max(basis.shape[0] for basis, _ in parts)
        maps = [
            torch.einsum("iy,ijm,jx->myx", wy, coefficients.reshape(len(node_rows), len(node_cols), -1), wx)
            for _, coefficients in parts
        ]
        r = k // 2
        return SourceTile(
            rows=rows,
            cols=cols,
            out_rows=(max(rows[0] - r, 0), min(rows[1] + r, self.height)),
            out_cols=(max(cols[0] - r, 0), min(cols[1] + r, self.width)),
            grid=tile_grid(rows, cols, (self.height, self.width), k),
            basis=torch.stack([_pad_rank(basis, rank) for basis, _ in parts]),
            coefficients=torch.stack([_pad_rank(m, rank) for m in maps]),
        )

    @property
    def rank(self) -> int:
        """The largest ``M_t``: basis kernels (convolutions) per tile per application; with one tile, ``M``."""
        return max(tile.rank for tile in self.source_tiles)

    @property
    def convolutions(self) -> int:
        """``sum_t M_t``: the (tile-sized) convolutions per application."""
        return sum(tile.rank for tile in self.source_tiles)

    @property
    def tile_ranks(self) -> np.ndarray:
        """``(Ty, Tx)`` the tiles' ranks ``M_t``."""
        return np.array([tile.rank for tile in self.source_tiles]).reshape(self.tiles)

    @property
    def grid(self) -> tuple[int, int]:
        """The FFT grid of the first tile (with one tile, the whole image's :func:`.convolution.fft_shape`)."""
        return self.source_tiles[0].grid

    @property
    def channels(self) -> int:
        """Colour channels of the kernels (1: one set for every colour)."""
        return int(self.kernels.shape[2])

    def _parts(self, like: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per tile (coefficient maps ``(C|1, M_t, th, tw)``, transfer functions ``(C|1, M_t, Gh, Gw//2+1)``)."""
        key = (like.dtype, like.device)
        if key not in self._cache:
            self._cache[key] = [
                (
                    tile.coefficients.to(like.device, like.dtype),
                    optical_transfer_function(tile.basis.to(like.device, like.dtype), tile.grid),
                )
                for tile in self.source_tiles
            ]
        return self._cache[key]

    def _check(self, image: torch.Tensor) -> None:
        if image.ndim != 4 or tuple(image.shape[-2:]) != (self.height, self.width):
            raise EdofprojError(
                f"the blur is set up for (B, C, {self.height}, {self.width}) images, got {tuple(image.shape)}"
            )
        if self.channels not in (1, image.shape[1]):
            raise EdofprojError(f"{self.channels}-channel node kernels for a {image.shape[1]}-channel image")
        if not image.is_floating_point():
            raise EdofprojError(f"the blur needs a floating-point image, got {image.dtype}")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``A x = sum_t P_t sum_m e_tm (*) (c_tm . x|T_t)``: ``x (B, C, H, W)`` -> ``(B, C, H, W)``."""
        self._check(x)
        parts = self._parts(x)
        scipy_path = _on_scipy(x)
        out = None
        for index, (tile, (maps, otf)) in enumerate(zip(self.source_tiles, parts)):
            (y0, y1), (x0, x1) = tile.rows, tile.cols
            (oy0, oy1), (ox0, ox1) = tile.out_rows, tile.out_cols
            sources = x[..., y0:y1, x0:x1]
            spectrum: torch.Tensor | None
            if scipy_path:
                spectrum = self._forward_batched(sources, maps, otf, tile, index)
            else:
                spectrum = None
                oy, ox = tile.offset
                pad = (ox, tile.grid[1] - ox - (x1 - x0), oy, tile.grid[0] - oy - (y1 - y0))
                for m in range(tile.rank):
                    framed = torch.nn.functional.pad(sources * maps[:, m], pad)
                    term = torch.fft.rfft2(framed) * otf[:, m]
                    spectrum = term if spectrum is None else spectrum.add_(term)
            assert spectrum is not None
            light = _irfft2(spectrum, tile.grid)[..., : oy1 - oy0, : ox1 - ox0]
            if len(self.source_tiles) == 1:
                return light
            if out is None:
                out = torch.zeros(x.shape, dtype=light.dtype, device=x.device)
            out[..., oy0:oy1, ox0:ox1] += light
        assert out is not None
        return out

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """``(A^T y)|T_t = sum_m c_tm . (e_tm (x) P_t^T y)``, the exact transpose of :meth:`forward`."""
        self._check(y)
        parts = self._parts(y)
        scipy_path = _on_scipy(y)
        out = torch.zeros_like(y)
        for index, (tile, (maps, otf)) in enumerate(zip(self.source_tiles, parts)):
            (y0, y1), (x0, x1) = tile.rows, tile.cols
            (oy0, oy1), (ox0, ox1) = tile.out_rows, tile.out_cols
            oy, ox = tile.offset
            spectrum = _rfft2(y[..., oy0:oy1, ox0:ox1], tile.grid)
            target = out[..., y0:y1, x0:x1]
            if scipy_path:
                conjugate = self._conjugate(y, index, otf)
                for first, last in self._chunks(y, index):
                    products = spectrum[:, :, None] * conjugate[None, :, first:last]  # (B, C, m, Gh, Gw/2+1)
                    spread = _irfft2(products, tile.grid)[..., oy : oy + y1 - y0, ox : ox + x1 - x0]
                    for m in range(last - first):
                        target.addcmul_(spread[:, :, m], maps[:, first + m])
                continue
            for m in range(tile.rank):
                spread = _irfft2(spectrum * otf[:, m].conj(), tile.grid)[..., oy : oy + y1 - y0, ox : ox + x1 - x0]
                target.addcmul_(spread, maps[:, m])
        return out

    def _conjugate(self, like: torch.Tensor, index: int, otf: torch.Tensor) -> torch.Tensor:
        """``conj(otf)`` of tile ``index`` materialized, kept per dtype and device."""
        key = (like.dtype, like.device)
        if key not in self._conjugates:
            self._conjugates[key] = [otf_t.conj().resolve_conj() for _, otf_t in self._parts(like)]
        return self._conjugates[key][index]

    def _chunks(self, like: torch.Tensor, index: int = 0) -> list[tuple[int, int]]:
        """Ranges of tile ``index``'s basis indices transformed together: at most :data:`BATCH_ELEMENTS` real
        samples a batch."""
        tile = self.source_tiles[index]
        per_term = like.shape[0] * like.shape[1] * tile.grid[0] * tile.grid[1]
        size = max(1, BATCH_ELEMENTS // per_term)
        return [(first, min(first + size, tile.rank)) for first in range(0, tile.rank, size)]

    def _frames(self, shape: tuple[int, ...], dtype: torch.dtype, window: tuple) -> torch.Tensor:
        """A zero-padded frame buffer of ``shape``: one block kept between calls (fresh pages cost as much as
        the transforms), re-zeroed unless its last use was the same ``shape`` and ``window`` (whose padding is
        then still zero)."""
        size = int(np.prod(shape))
        key = (shape, dtype, window)
        if self._buffer is None or self._buffer[1].dtype != dtype or self._buffer[1].numel() < size:
            self._buffer = (key, torch.zeros(size, dtype=dtype))
            return self._buffer[1][:size].view(shape)
        frames = self._buffer[1][:size].view(shape)
        if self._buffer[0] != key:
            frames.zero_()
            self._buffer = (key, self._buffer[1])
        return frames

    def _forward_batched(
        self, sources: torch.Tensor, maps: torch.Tensor, otf: torch.Tensor, tile: SourceTile, index: int
    ) -> torch.Tensor:
        """The spectrum of tile ``index``'s light on the CPU outside autograd: the products ``c_tm . x`` of a
        chunk of terms written into one zero-padded frame buffer (:meth:`_frames`) and transformed by one
        multi-threaded :func:`scipy.fft.rfft2` call; the spectra weighted by the transfer functions and summed."""
        spectrum = None
        oy, ox = tile.offset
        th, tw = tile.shape
        for first, last in self._chunks(sources, index):
            shape = (sources.shape[0], sources.shape[1], last - first, *tile.grid)
            frames = self._frames(shape, sources.dtype, (oy, ox, th, tw))
            torch.mul(sources[:, :, None], maps[None, :, first:last], out=frames[..., oy : oy + th, ox : ox + tw])
            terms = torch.from_numpy(scipy.fft.rfft2(frames.numpy(), workers=torch.get_num_threads()))
            for j in range(last - first):
                if spectrum is None:
                    spectrum = terms[:, :, j] * otf[:, first + j]
                else:
                    spectrum.addcmul_(terms[:, :, j], otf[:, first + j])
        assert spectrum is not None
        return spectrum

    __call__ = forward

    def norm_bound(self) -> torch.Tensor:
        """An upper bound of ``||A||_2`` per channel ``(C|1,)`` by Schur's test, ``sqrt(max_y sum_x |A_yx|
        max_x sum_y |A_yx|)``, for non-negative node kernels (the sums are then ``A 1`` and ``A^T 1``,
        computed exactly)."""
        if bool((self.kernels < 0).any()):
            raise EdofprojError("Schur's bound here needs non-negative node kernels")
        if self._norm_bound is None:  # computed once: every image compensated under this blur needs it
            ones = torch.ones((1, self.channels, self.height, self.width), dtype=torch.float64)
            rows = self.forward(ones).amax(dim=(0, 2, 3))
            cols = self.adjoint(ones).amax(dim=(0, 2, 3))
            self._norm_bound = torch.sqrt(rows.clamp_min(0) * cols.clamp_min(0))
        return self._norm_bound.clone()


def _on_scipy(tensor: torch.Tensor) -> bool:
    """A CPU tensor outside autograd: transformed by :mod:`scipy.fft` (about half the CPU time of
    ``torch.fft`` there), the same transform to rounding."""
    return tensor.device.type == "cpu" and not (torch.is_grad_enabled() and tensor.requires_grad)


def _rfft2(image: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
    """``torch.fft.rfft2(image, s=grid)``."""
    if _on_scipy(image):
        return torch.from_numpy(scipy.fft.rfft2(image.numpy(), s=grid, workers=torch.get_num_threads()))
    return torch.fft.rfft2(image, s=grid)


def _irfft2(spectrum: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
    """``torch.fft.irfft2(spectrum, s=grid)``; on SciPy as the complex inverse along the rows' axis, then the
    real one along the last (the same transform; less CPU time than :func:`scipy.fft.irfft2` there)."""
    if _on_scipy(spectrum):
        workers = torch.get_num_threads()
        columns = scipy.fft.ifft(spectrum.numpy(), n=grid[0], axis=-2, workers=workers)
        return torch.from_numpy(scipy.fft.irfft(columns, n=grid[1], axis=-1, workers=workers))
    return torch.fft.irfft2(spectrum, s=grid)


def _pad_rank(tensor: torch.Tensor, rank: int) -> torch.Tensor:
    """``tensor (M, ...)`` zero-padded along its first axis to ``rank``."""
    if tensor.shape[0] == rank:
        return tensor
    return torch.cat([tensor, tensor.new_zeros((rank - tensor.shape[0],) + tuple(tensor.shape[1:]))])
