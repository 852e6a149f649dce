"""Linear 2-D convolution by FFT, with zero padding and 'same' output alignment.

For an image ``I`` of ``H x W`` pixels and a kernel ``p`` of ``Kh x Kw`` pixels the output is

    out[y, x] = sum_{i, j} I[y + Kh//2 - i, x + Kw//2 - j] * p[i, j],

with ``I`` taken as zero outside the image. The kernel's pixel ``(Kh//2, Kw//2)`` (the
optical axis of a PSF) therefore lands on the source pixel itself, and the output has the
input's size. This is ``scipy.signal.fftconvolve(I, p, mode='same')`` for odd kernels.

Computation: both arrays are zero-padded to at least ``(H + Kh - 1) x (W + Kw - 1)`` (rounded
up to a fast FFT length, :func:`scipy.fft.next_fast_len`) so the circular convolution of
the DFT equals the linear one (no wrap-around); then ``irfft2(rfft2(I) * rfft2(p))`` is
cropped. Everything is ``torch`` and differentiable in both arguments.
"""

from __future__ import annotations

import scipy.fft
import torch

from ..errors import EdofprojError


def fast_fft_length(n: int) -> int:
    """The smallest length ``>= n`` whose real FFT is fast (a 2-3-5-smooth number)."""
    return int(scipy.fft.next_fast_len(int(n), real=True))


def padded_shape(image_hw: tuple[int, int], kernel_hw: tuple[int, int]) -> tuple[int, int]:
    """FFT size that makes a circular convolution linear: ``>= H + Kh - 1``, ``>= W + Kw - 1``."""
    return (fast_fft_length(image_hw[0] + kernel_hw[0] - 1), fast_fft_length(image_hw[1] + kernel_hw[1] - 1))


def convolve_same(image: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Linear convolution of ``image (..., H, W)`` with ``kernel (..., Kh, Kw)``, output ``(..., H, W)``.

    Leading dimensions broadcast, so an image batch ``(B, C, H, W)`` takes one PSF for all
    samples ``(1, C, K, K)``, one per sample ``(B, C, K, K)``, or one for all channels
    ``(1, 1, K, K)``. The kernel is cast to the image's dtype. See the module docstring for
    the alignment (kernel pixel ``K//2`` maps onto the source pixel).
    """
    if image.ndim < 2 or kernel.ndim < 2:
        raise EdofprojError(
            f"convolution needs 2-D images and kernels, got shapes {tuple(image.shape)} and {tuple(kernel.shape)}"
        )
    lead_image, lead_kernel = image.shape[:-2], kernel.shape[:-2]
    try:
        torch.broadcast_shapes(lead_image, lead_kernel)
    except RuntimeError:
        raise EdofprojError(
            f"image {tuple(image.shape)} and PSF {tuple(kernel.shape)} do not match: the PSF needs a batch of 1 or "
            f"{tuple(lead_image)[:1]} and 1 or the image's channels"
        ) from None
    if not image.is_floating_point():
        raise EdofprojError(f"convolution needs a floating-point image, got {image.dtype}")
    H, W = image.shape[-2:]
    Kh, Kw = kernel.shape[-2:]
    size = padded_shape((H, W), (Kh, Kw))
    kernel = kernel.to(dtype=image.dtype, device=image.device)
    spectrum = torch.fft.rfft2(image, s=size) * torch.fft.rfft2(kernel, s=size)
    full = torch.fft.irfft2(spectrum, s=size)
    return full[..., Kh // 2 : Kh // 2 + H, Kw // 2 : Kw // 2 + W]
