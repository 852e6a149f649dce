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

Shapes: image ``(B, C, H, W)``; ``psf_grid`` ``(Gy, Gx, C or 1, K, K)``; centres in pixels
(``(Gy,)`` rows, ``(Gx,)`` columns, increasing). :func:`field_centres_px` maps normalized
field coordinates in [-1, 1] (the image edges) to pixel centres.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft
import torch

from ..errors import EdofprojError
from .convolution import convolve_same, fft_shape, optical_transfer_function

BATCH_ELEMENTS = 1 << 23
"""Real samples (frames x padded pixels) :class:`FieldVaryingBlur` transforms in one batched FFT call on the CPU:
32 MiB in float32, the largest block the C library's allocator reuses instead of mapping fresh pages (whose
faults cost as much system time as the transforms)."""


def field_centres_px(field_coords, size_px: int) -> np.ndarray:
    """Pixel coordinates of normalized field coordinates: -1 is the outer edge of the first
    pixel (-0.5), +1 that of the last (``size_px - 0.5``)."""
    f = np.asarray(field_coords, dtype=float)
    return (f + 1.0) / 2.0 * size_px - 0.5


def node_centres_px(size_px: int, spacing_px: float) -> np.ndarray:
    """``ceil((size - 1) / spacing) + 1`` nodes (at least 2) evenly from pixel 0 to pixel ``size - 1``, at
    most ``spacing_px`` apart."""
    if not float(spacing_px) >= 1:
        raise EdofprojError(f"a node spacing of {spacing_px} px must be >= 1")
    count = max(math.ceil((int(size_px) - 1) / float(spacing_px)) + 1, 2)
    return np.linspace(0.0, float(size_px - 1), count)


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
    kernels: torch.Tensor, tolerance: float = 0.0, sketches: tuple[int, ...] = (32, 64)
) -> tuple[torch.Tensor, torch.Tensor]:
    """``kernels (N, Kh, Kw) ~= sum_m coefficients[:, m] basis[m]``: the truncated singular value
    decomposition of the ``N x Kh Kw`` matrix ``X`` of the kernels, keeping the fewest ``M`` components whose
    dropped singular values ``sigma_m`` satisfy ``sqrt(sum_dropped sigma_m^2) <= tolerance * ||X||_F``
    (``tolerance = 0``: all above ``1e-12 sigma_0``, exact to rounding). Returns ``basis (M, K, K)`` (orthonormal)
    and ``coefficients (N, M)`` float64. With more kernels than taps (``N > K^2``) the right singular
    vectors are the eigenvectors of ``X^T X`` (a ``K^2 x K^2`` problem, whatever ``N``). Many large kernels
    with a tolerance: the randomized basis of :func:`_randomized_low_rank`, sketches of ``sketches`` vectors
    tried in turn (the first that reaches the tolerance), the exact decomposition if none does."""
    n, (kh, kw) = kernels.shape[0], kernels.shape[-2:]
    taps = kh * kw
    matrix = kernels.reshape(n, taps).to(torch.float64)
    if float(tolerance) > 0 and n * taps > 4_000_000:
        for most in sketches:
            sketched = _randomized_low_rank(matrix, float(tolerance), most)
            if sketched is not None:
                return sketched.T.reshape(sketched.shape[1], kh, kw), matrix @ sketched
    if n * taps <= 4_000_000:
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
    rank = max(int((energy > 1e-24 * energy[0]).sum()), 1)  # the numerical rank (singular values > 1e-12 sigma_0)
    if float(tolerance) > 0:
        dropped = torch.flip(torch.cumsum(torch.flip(energy, (0,)), 0), (0,))  # dropped[m]: energy beyond m terms
        bound = float(tolerance) ** 2 * float(energy.sum())
        rank = next((m for m in range(1, len(energy)) if float(dropped[m]) <= bound), len(energy))
    basis = vectors[:, :rank]
    return basis.T.reshape(rank, kh, kw), matrix @ basis


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
    nodes there are. ``M`` is the kernels' rank (exact: ``rank_tolerance = 0``) or the fewest basis
    kernels within ``rank_tolerance`` (relative Frobenius error of all node kernels together); the
    truncated operator is the one applied, and its adjoint is exact for it.

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
    ):
        kernels = torch.as_tensor(kernels)
        if kernels.ndim != 5 or kernels.shape[-1] != kernels.shape[-2] or kernels.shape[-1] % 2 == 0:
            raise EdofprojError(f"node kernels must be (Gy, Gx, C or 1, K, K) with K odd, got {tuple(kernels.shape)}")
        if not torch.isfinite(kernels).all():
            raise EdofprojError("the node kernels contain NaN or infinite values")
        gy, gx, channels, k = kernels.shape[0], kernels.shape[1], kernels.shape[2], kernels.shape[-1]
        if len(centres_y_px) != gy or len(centres_x_px) != gx:
            raise EdofprojError(f"{gy} x {gx} node kernels but {len(centres_y_px)} x {len(centres_x_px)} centres")
        if not (0.0 <= float(rank_tolerance) < 1.0):
            raise EdofprojError(f"rank tolerance {rank_tolerance} must be in [0, 1)")
        self.height, self.width = int(image_hw[0]), int(image_hw[1])
        self.kernels = kernels
        self.centres_y_px = np.asarray(centres_y_px, dtype=np.float64)
        self.centres_x_px = np.asarray(centres_x_px, dtype=np.float64)
        wy = torch.as_tensor(hat_weights(centres_y_px, self.height))  # (Gy, H)
        wx = torch.as_tensor(hat_weights(centres_x_px, self.width))  # (Gx, W)
        bases, maps = [], []
        for c in range(channels):
            basis, coefficients = low_rank_kernels(kernels[:, :, c].reshape(gy * gx, k, k), rank_tolerance)
            bases.append(basis)
            maps.append(torch.einsum("iy,ijm,jx->myx", wy, coefficients.reshape(gy, gx, -1), wx))
        rank = max(b.shape[0] for b in bases)
        #: each kernel channel's own rank (the terms past it are zero padding, skipped on the CPU path)
        self.channel_ranks = [int(b.shape[0]) for b in bases]
        #: ``(C|1, M, K, K)`` orthonormal basis kernels ``e_m`` (zero-padded to the largest rank).
        self.basis = torch.stack([_pad_rank(b, rank) for b in bases])
        #: ``(C|1, M, H, W)`` the maps ``c_m`` (float64).
        self.coefficients = torch.stack([_pad_rank(m, rank) for m in maps])
        self.grid = fft_shape((self.height, self.width), (k, k))
        self._cache: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}
        self._buffers: dict[tuple, torch.Tensor] = {}
        self._conjugates: tuple[torch.Tensor, torch.Tensor] | None = None
        self._norm_bound: torch.Tensor | None = None

    @property
    def rank(self) -> int:
        """``M``: basis kernels (convolutions) per application."""
        return int(self.basis.shape[1])

    @property
    def channels(self) -> int:
        """Colour channels of the kernels (1: one set for every colour)."""
        return int(self.basis.shape[0])

    def _parts(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(coefficient maps ``(C|1, M, H, W)``, transfer functions ``(C|1, M, Gh, Gw//2+1)``) for ``like``."""
        key = (like.dtype, like.device)
        if key not in self._cache:
            otf = optical_transfer_function(self.basis.to(like.device, like.dtype), self.grid)
            self._cache[key] = (self.coefficients.to(like.device, like.dtype), otf)
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
        """``A x = sum_m e_m (*) (c_m . x)``: ``x (B, C, H, W)`` -> ``(B, C, H, W)``."""
        self._check(x)
        maps, otf = self._parts(x)
        if _on_scipy(x):
            parts = [self._forward_batched(x[:, i], maps[k, :r], otf[k, :r]) for i, k, r in self._colour_groups()]
            return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)
        spectrum = None
        for m in range(self.rank):
            term = _rfft2(x * maps[:, m], self.grid) * otf[:, m]
            spectrum = term if spectrum is None else spectrum.add_(term)
        assert spectrum is not None
        return _irfft2(spectrum, self.grid)[..., : self.height, : self.width]

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """``A^T y = sum_m c_m . (e_m (x) y)``, the exact transpose of :meth:`forward`."""
        self._check(y)
        maps, otf = self._parts(y)
        spectrum = _rfft2(y, self.grid)
        out = torch.zeros_like(y)
        if _on_scipy(y):
            conjugate = self._conjugate(otf)
            for i, k, rank in self._colour_groups():
                for first, last in self._chunks(y[:, i], rank):
                    products = spectrum[:, i, None] * conjugate[None, k, first:last]  # (B, C, m, Gh, Gw/2+1)
                    spread = _irfft2(products, self.grid)[..., : self.height, : self.width]
                    for m in range(last - first):
                        out[:, i].addcmul_(spread[:, :, m], maps[k, first + m])
            return out
        for m in range(self.rank):
            spread = _irfft2(spectrum * otf[:, m].conj(), self.grid)[..., : self.height, : self.width]
            out.addcmul_(spread, maps[:, m])
        return out

    def _colour_groups(self) -> list[tuple[slice, slice, int]]:
        """``(image channels, kernel channels, terms)`` transformed together on the CPU: all at once when
        every kernel channel has the full rank, else each colour with its own rank (its padding skipped)."""
        if min(self.channel_ranks) == self.rank:
            return [(slice(None), slice(None), self.rank)]
        return [(slice(c, c + 1), slice(c, c + 1), r) for c, r in enumerate(self.channel_ranks)]

    def _conjugate(self, otf: torch.Tensor) -> torch.Tensor:
        """``conj(otf)`` materialized, kept for the transfer functions ``otf`` of :meth:`_parts`."""
        if self._conjugates is None or self._conjugates[0] is not otf:
            self._conjugates = (otf, otf.conj().resolve_conj())
        return self._conjugates[1]

    def _chunks(self, like: torch.Tensor, rank: int | None = None) -> list[tuple[int, int]]:
        """Ranges of the first ``rank`` (default all) basis indices transformed together: at most
        :data:`BATCH_ELEMENTS` real samples a batch."""
        rank = self.rank if rank is None else int(rank)
        per_term = like.shape[0] * like.shape[1] * self.grid[0] * self.grid[1]
        size = max(1, BATCH_ELEMENTS // per_term)
        return [(first, min(first + size, rank)) for first in range(0, rank, size)]

    def _forward_batched(self, x: torch.Tensor, maps: torch.Tensor, otf: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` on the CPU outside autograd: the products ``c_m . x`` of a chunk of terms written
        into one zero-padded frame buffer (kept between calls: its padding stays zero) and transformed by one
        multi-threaded :func:`scipy.fft.rfft2` call; the spectra weighted by the transfer functions and summed."""
        spectrum = None
        for first, last in self._chunks(x, maps.shape[1]):
            shape = (x.shape[0], x.shape[1], last - first, *self.grid)
            key = (shape, x.dtype)
            if key not in self._buffers:
                self._buffers[key] = torch.zeros(shape, dtype=x.dtype)
            frames = self._buffers[key]
            torch.mul(x[:, :, None], maps[None, :, first:last], out=frames[..., : self.height, : self.width])
            terms = torch.from_numpy(scipy.fft.rfft2(frames.numpy(), workers=torch.get_num_threads()))
            for j in range(last - first):
                if spectrum is None:
                    spectrum = terms[:, :, j] * otf[:, first + j]
                else:
                    spectrum.addcmul_(terms[:, :, j], otf[:, first + j])
        assert spectrum is not None
        return _irfft2(spectrum, self.grid)[..., : self.height, : self.width]

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
