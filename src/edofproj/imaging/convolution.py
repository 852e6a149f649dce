"""The FFT convolution operator of the whole project: one PSF, its transfer function, and its use.

For an image ``I`` of ``H x W`` pixels and a kernel ``p`` of ``Kh x Kw`` pixels, the linear
'same' convolution is

    out[y, x] = sum_{i, j} I[y + Kh//2 - i, x + Kw//2 - j] * p[i, j],

with ``I`` taken as zero outside the image. The kernel's pixel ``(Kh//2, Kw//2)`` (the optical
axis of a PSF) lands on the source pixel itself, and the output has the input's size. This is
``scipy.signal.fftconvolve(I, p, mode='same')`` for odd kernels.

Everything that filters an image with a PSF in the Fourier domain goes through three pieces:

* :func:`optical_transfer_function` -- ``H = rfft2(p)`` on an FFT grid, with the optical axis
  moved to pixel ``(0, 0)`` (*centring*, so ``H`` carries no linear phase) and, optionally, the
  DC gain set to 1 (*haze*: the light ``1 - sum p`` outside the PSF window comes back as a
  uniform haze, so the projection keeps the mean brightness; see :mod:`.projection`);
* :func:`fft_shape` -- the grid that makes the circular convolution of the DFT equal the linear
  one on the cropped frame (*zero padding*): at least ``(H + Kh//2) x (W + Kw//2)`` (and the kernel's size), rounded up
  to a fast FFT length (:func:`fast_fft_length`). Pixels ``y - s`` with a shift
  ``|s| <= Kh//2`` that fall outside the image then land on padded zeros, never on the other side;
* :func:`apply_transfer_function` -- zero-pad the image to the grid, multiply its spectrum by a
  transfer function, crop ``[:H, :W]``.

:func:`convolve_same` is the three together; the projection (:mod:`.projection`), the Wiener
filters and the constrained least-squares operator (:mod:`edofproj.compensation`) build on the
same pieces. Everything is ``torch`` and differentiable in the image and the PSF.

**In an ONNX export** (``torch.onnx.is_in_onnx_export()``) :class:`KernelConvolution` (and so
:func:`convolve_same` and the projection) computes the same convolution on the same grid with the
DFT written as matrix products (:mod:`.matrix_dft`), which ONNX Runtime runs several times faster
than its ``DFT`` operator; its transfer function is then in :mod:`.matrix_dft`'s transposed half
layout (:func:`matrix_transfer_function`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..errors import EdofprojError
from . import matrix_dft


def fast_fft_length(n: int) -> int:
    """The smallest length ``>= n`` whose real FFT is fast: the smallest ``2^a 3^b 5^c >= n`` (a 5-smooth
    number; what ``scipy.fft.next_fast_len(n, real=True)`` returns, without importing :mod:`scipy.fft`,
    a third of a second of every command's start).

    For each odd factor ``3^b 5^c < 2 n`` the power of 2 that lifts it to ``n`` or more is the candidate."""
    n = int(n)
    if n < 1:
        raise EdofprojError(f"an FFT length must be >= 1, got {n}")
    best = 2 * n  # the power of 2 alone (3^0 5^0) is below it
    five = 1
    while five < 2 * n:
        odd = five
        while odd < 2 * n:
            best = min(best, odd << max(0, ((n + odd - 1) // odd - 1).bit_length()))
            odd *= 3
        five *= 5
    return best


def fft_shape(image_hw: tuple[int, int], kernel_hw: tuple[int, int]) -> tuple[int, int]:
    """FFT grid on which a centred kernel's circular convolution is linear: ``>= max(H + Kh//2, Kh)`` rows, likewise columns.

    (``>= Kh`` keeps the kernel's taps from overlapping themselves when it is larger than the image.)
    """
    rows = max(image_hw[0] + kernel_hw[0] // 2, kernel_hw[0])
    cols = max(image_hw[1] + kernel_hw[1] // 2, kernel_hw[1])
    return (fast_fft_length(rows), fast_fft_length(cols))


def centred_kernel(psf: torch.Tensor, grid_hw: tuple[int, int]) -> torch.Tensor:
    """``psf (..., Kh, Kw)`` zero-padded to ``grid_hw`` and rolled by ``(-Kh//2, -Kw//2)``: its optical
    axis at pixel ``(0, 0)``; ``(..., Gh, Gw)``."""
    kh, kw = psf.shape[-2:]
    gh, gw = int(grid_hw[0]), int(grid_hw[1])
    if kh > gh or kw > gw:
        raise EdofprojError(f"a {kh}x{kw} PSF does not fit in a {gh}x{gw} FFT grid")
    kernel = F.pad(psf, (0, gw - kw, 0, gh - kh))
    return torch.roll(kernel, shifts=(-(kh // 2), -(kw // 2)), dims=(-2, -1))


def optical_transfer_function(psf: torch.Tensor, grid_hw: tuple[int, int], haze: bool = False) -> torch.Tensor:
    """``H = rfft2(p)`` of ``psf (..., Kh, Kw)`` on a ``grid_hw`` grid, optical axis at pixel ``(0, 0)``.

    The kernel is zero-padded to the grid and rolled by ``(-Kh//2, -Kw//2)``, so its pixel
    ``(Kh//2, Kw//2)`` sits at the origin and ``H`` is real for a centro-symmetric PSF. With
    ``haze`` the zero-frequency bin is set to 1: the haze ``(1 - sum p) mean(I)`` adds exactly
    the DC gain the window lost (exact for a periodic frame). Returns complex ``(..., Gh, Gw//2 + 1)``;
    differentiable in ``psf`` (the DC bin does not depend on it when ``haze``).
    """
    otf = torch.fft.rfft2(centred_kernel(psf, grid_hw))
    if haze:
        otf = otf.clone()
        otf[..., 0, 0] = 1.0
    return otf


def apply_transfer_function(image: torch.Tensor, otf: torch.Tensor, grid_hw: tuple[int, int]) -> torch.Tensor:
    """``crop(irfft2(rfft2(pad0(I)) * H))``: ``image (..., H, W)`` zero-padded to ``grid_hw``, filtered, cropped.

    ``otf (..., Gh, Gw//2 + 1)`` broadcasts against the image's spectrum (e.g. one transfer
    function for a batch). Returns ``(..., H, W)``.
    """
    height, width = image.shape[-2:]
    grid = (int(grid_hw[0]), int(grid_hw[1]))
    spectrum = torch.fft.rfft2(image, s=grid) * otf
    return torch.fft.irfft2(spectrum, s=grid)[..., :height, :width]


def matrix_transfer_function(psf: torch.Tensor, grid_hw: tuple[int, int]) -> torch.Tensor:
    """:func:`optical_transfer_function` (without haze) in :mod:`.matrix_dft`'s transposed half layout,
    computed with its matrix products: real ``(..., 2, Gw, Gh // 2 + 1)`` (real and imaginary parts)."""
    return matrix_dft.rfft2(centred_kernel(psf, grid_hw), grid_hw)


def apply_matrix_transfer_function(
    image: torch.Tensor, transfer: torch.Tensor, grid_hw: tuple[int, int]
) -> torch.Tensor:
    """:func:`apply_transfer_function` with a :func:`matrix_transfer_function` (the export form)."""
    height, width = image.shape[-2:]
    spectrum = matrix_dft.complex_multiply(matrix_dft.rfft2(image, grid_hw), transfer)
    return matrix_dft.irfft2(spectrum, grid_hw, rows=(0, height), cols=(0, width))


def broadcastable(shape_a, shape_b) -> bool:
    """Whether two shapes broadcast (aligned at their last dimensions, each pair equal or one of them 1).

    The rule written out rather than ``torch.broadcast_shapes``, whose first call imports SymPy (about a
    second of a command's start-up)."""
    return all(a == b or a == 1 or b == 1 for a, b in zip(reversed(tuple(shape_a)), reversed(tuple(shape_b))))


class KernelConvolution:
    """``image -> convolve_same(image, kernel)`` for one kernel and many images.

    The kernel's transfer function is computed on the first image of each FFT grid (size,
    dtype, device) and reused, so filtering several images of one size with the same PSFs (the
    uncompensated and the compensated projection of a training step) transforms the kernel once.
    Differentiable in the images and the kernel (the cached transfer function stays in the graph).
    """

    def __init__(self, kernel: torch.Tensor) -> None:
        if kernel.ndim < 2:
            raise EdofprojError(f"convolution needs 2-D kernels, got shape {tuple(kernel.shape)}")
        self.kernel = kernel
        self._transfer: dict[tuple, torch.Tensor] = {}

    def __call__(self, image: torch.Tensor) -> torch.Tensor:
        kernel = self.kernel
        if image.ndim < 2:
            raise EdofprojError(
                f"convolution needs 2-D images and kernels, got shapes {tuple(image.shape)} and {tuple(kernel.shape)}"
            )
        lead_image, lead_kernel = image.shape[:-2], kernel.shape[:-2]
        if not broadcastable(lead_image, lead_kernel):
            raise EdofprojError(
                f"image {tuple(image.shape)} and PSF {tuple(kernel.shape)} do not match: the PSF needs a batch of 1 "
                f"or {tuple(lead_image)[:1]} and 1 or the image's channels"
            )
        if not image.is_floating_point():
            raise EdofprojError(f"convolution needs a floating-point image, got {image.dtype}")
        grid = fft_shape((image.shape[-2], image.shape[-1]), (kernel.shape[-2], kernel.shape[-1]))
        exported = torch.onnx.is_in_onnx_export()  # the DFT as matrix products (module docstring)
        key = (grid, image.dtype, image.device, exported)
        if key not in self._transfer:
            transfer_function = matrix_transfer_function if exported else optical_transfer_function
            self._transfer[key] = transfer_function(kernel.to(dtype=image.dtype, device=image.device), grid)
        apply = apply_matrix_transfer_function if exported else apply_transfer_function
        return apply(image, self._transfer[key], grid)


def convolve_same(image: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Linear convolution of ``image (..., H, W)`` with ``kernel (..., Kh, Kw)``, output ``(..., H, W)``.

    Leading dimensions broadcast, so an image batch ``(B, C, H, W)`` takes one PSF for all
    samples ``(1, C, K, K)``, one per sample ``(B, C, K, K)``, or one for all channels
    ``(1, 1, K, K)``. The kernel is cast to the image's dtype. See the module docstring for
    the alignment (kernel pixel ``K//2`` maps onto the source pixel). (:class:`KernelConvolution`
    keeps the kernel's transfer function for further images.)
    """
    return KernelConvolution(kernel)(image)
