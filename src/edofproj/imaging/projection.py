"""Projection onto a screen at one depth (paper Eq. 9) with the haze of docs/physics.md "Energy".

The projector can only emit light in ``[0, 1]``, so the image is clamped first. Light of a
source pixel lands according to the PSF ``p`` (each value the pixel's share of the energy
through the pupil). The PSF window holds ``E = sum p <= 1`` of it; the remaining ``1 - E``
is spread thin over the whole screen and is modelled as a uniform haze:

    project(I) = clamp(I, 0, 1) (*) p  +  (1 - sum p) * mean(clamp(I, 0, 1))     (per channel)

where ``(*)`` is the linear 'same' convolution of :mod:`.convolution`. Consequences, exact
up to rounding:

* a uniform image ``c`` stays ``c`` at every pixel at least ``K//2`` from the border;
* on a canvas that has a black margin of ``K//2`` pixels around the content, the total
  light is conserved: ``sum project(I) = sum I``;
* with a unit impulse PSF (centre 1, zeros elsewhere) the projection is the identity on
  ``[0, 1]`` images.
"""

from __future__ import annotations

import torch

from ..errors import EdofprojError
from .convolution import KernelConvolution


def _check_image_and_psf(image: torch.Tensor, psf: torch.Tensor) -> None:
    if image.ndim != 4:
        raise EdofprojError(f"images must be (B, C, H, W), got shape {tuple(image.shape)}")
    if psf.ndim != 4 or psf.shape[-1] != psf.shape[-2]:
        raise EdofprojError(f"PSFs must be (B or 1, C or 1, K, K), got shape {tuple(psf.shape)}")
    if psf.shape[0] not in (1, image.shape[0]) or psf.shape[1] not in (1, image.shape[1]):
        raise EdofprojError(
            f"PSF shape {tuple(psf.shape)} does not fit images {tuple(image.shape)}: "
            f"expected ({image.shape[0]} or 1, {image.shape[1]} or 1, K, K)"
        )


def haze_term(clamped_image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """The uniform haze ``(1 - sum p) * mean(I)`` per sample and channel, shape ``(B, C, 1, 1)``.

    ``clamped_image`` must already lie in ``[0, 1]`` (see :func:`project`).
    """
    lost = 1.0 - psf.sum(dim=(-1, -2), keepdim=True).to(clamped_image.dtype)
    return lost * clamped_image.mean(dim=(-1, -2), keepdim=True)


class ScreenProjection:
    """``image -> project(image, psf)`` for one screen and many images (:func:`project`).

    The PSF's transfer function is computed once per image size and reused
    (:class:`~edofproj.imaging.convolution.KernelConvolution`): the closed loop projects the
    uncompensated and the compensated image through the same PSFs.
    """

    def __init__(self, psf: torch.Tensor, haze: bool = True) -> None:
        if psf.ndim != 4 or psf.shape[-1] != psf.shape[-2]:
            raise EdofprojError(f"PSFs must be (B or 1, C or 1, K, K), got shape {tuple(psf.shape)}")
        self.psf = psf
        self.haze = haze
        self._convolution = KernelConvolution(psf)

    def __call__(self, image: torch.Tensor) -> torch.Tensor:
        _check_image_and_psf(image, self.psf)
        clamped = image.clamp(0.0, 1.0)
        out = self._convolution(clamped)
        if self.haze:
            out = out + haze_term(clamped, self.psf)
        return out


def project(image: torch.Tensor, psf: torch.Tensor, haze: bool = True) -> torch.Tensor:
    """What a screen at one depth shows when the projector emits ``image``.

    ``image (B, C, H, W)``, any values (clamped to ``[0, 1]`` here, as a projector would);
    ``psf (B or 1, C or 1, K, K)``. Returns ``(B, C, H, W)``: the clamped image convolved
    with the PSF plus, when ``haze`` is true, the energy the PSF window lost as a uniform
    haze (module docstring). Differentiable in ``image`` (inside ``[0, 1]``) and ``psf``.
    """
    _check_image_and_psf(image, psf)
    return ScreenProjection(psf, haze)(image)


#: Measured bytes per padded pixel of ``render``: a flat screen, and each extra depth layer
#: (peak RSS of ``edofproj render`` at 1000x1000 and 2000x3000 px, window 33, less the ~330 MiB of
#: the loaded libraries; docs/experiments/2026-11-23-fault-injection.md).
PROJECTION_BYTES_PER_PIXEL = 80
LAYER_BYTES_PER_PIXEL = 30


def projection_bytes(height: int, width: int, window: int, layers: int = 1) -> int:
    """Memory to project one ``height x width`` RGB image with ``window``-px PSFs on ``layers``
    depth layers (1: a flat screen): ``(80 + 30 (layers - 1)) (H + K - 1)(W + K - 1)`` bytes."""
    padded = (int(height) + window - 1) * (int(width) + window - 1)
    return (PROJECTION_BYTES_PER_PIXEL + LAYER_BYTES_PER_PIXEL * max(int(layers) - 1, 0)) * padded
