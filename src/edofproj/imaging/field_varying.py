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

import numpy as np
import torch

from ..errors import EdofprojError
from .convolution import convolve_same


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
