"""A network that is never far from its DOE's linear filter: a bounded correction on top of it.

The *safe* compensation (``net.linear_base: ensemble``) predicts the projector input as

    x = E(I) + c,      E(I) = clamp(g * I, 0, 1),      c = HP_s( b_t tanh( HP_s(r) / b_t ) )

* ``g`` is the depth-ensemble Wiener filter of the current DOE
  (:func:`~edofproj.compensation.wiener.depth_ensemble_wiener_kernel` of its PSFs at
  :func:`ensemble_depths_m`, ``(2 R + 1)^2`` taps, applied after reflecting the border by ``R``
  pixels): with the same PSFs, NSR and radius, ``E`` is exactly the blind baseline ``doe+ensemble``
  of the evaluation. The trainer recomputes ``g`` from the DOE it is optimizing
  (:mod:`edofproj.training.linear_base`) and keeps it in the network's state (a buffer), so a
  trained run carries the filter of its final DOE.
* ``r`` is the U-Net's output (it sees ``[I, I*, E(I)]``); its last layer starts at zero, so an
  untrained network *is* the linear filter, ``x = E(I)``.
* ``HP_s(v) = v - G_s * v`` removes a local mean (``G_s`` a normalized Gaussian of ``s`` pixels,
  replicate border). It is applied twice. Inside, ``HP_s(r)``: the residual's local mean never
  reaches the output, so it cannot push ``tanh`` into saturation (a residual whose mean has drifted
  would otherwise saturate ``tanh`` at every pixel, and with it stop every gradient to the
  U-Net). Outside, on the bounded value: the correction carries no level of its own, so over any
  flat area wider than a few ``s`` the emitted colour is the linear filter's, whatever the
  weights.
* ``b_t tanh(u / b_t)`` bounds the correction per pixel by ``b_t``. ``b_t = b / 2`` with the
  high-pass (``|HP_s(v)| <= 2 max|v|``), ``b`` without it (``c = b tanh(r / b)``).
* ``c`` is computed in float32 whatever the autocast (``HP_s`` of a bfloat16 residual would
  resolve only 8 bits of its value).

**The rule that makes it safe.** ``|x - E(I)| <= b`` at every pixel, for any weights. The
projection ``A(x) = clamp(x, 0, 1) * p + (1 - sum p) mean(clamp(x, 0, 1))`` is non-expansive in
the maximum norm (``clamp`` is 1-Lipschitz, ``p >= 0`` and the haze gain ``1 - sum p`` add up to
1), so at *every* depth ``|A(x) - A(E(I))| <= b`` per pixel: the network's display differs from the
linear filter's by at most ``b`` anywhere, on any image, and its RMS error exceeds the linear
filter's by at most ``b``. Flat colours (a near-empty primary included) keep the linear filter's
level, ``G(0) = 1 / (1 + NSR)`` of the target. Training then only has to find where the correction
helps; :mod:`edofproj.training.validation` checks that it does, image by image.
"""

from __future__ import annotations

import functools
import math
from typing import Callable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from ..imaging.convolution import convolve_same
from .wiener import depth_ensemble_wiener_kernel

#: Depths of the ensemble (uniform in 1/z over the scored range), as :func:`edofproj.evaluation.methods.ensemble_depths_m`.
ENSEMBLE_DEPTHS = 32
#: Frame (px) on which the ensemble filter is computed before it is cut to its taps (as the evaluation's).
ENSEMBLE_GRID = 256


def ensemble_depths_m(near_m: float, far_m: float, count: int = ENSEMBLE_DEPTHS) -> np.ndarray:
    """``count`` depths from ``near_m`` to ``far_m`` uniform in ``1/z`` (uniform in defocus)."""
    return 1.0 / np.linspace(1.0 / near_m, 1.0 / far_m, int(count))


class LinearBase(nn.Module):
    """``E(I) = clamp(g * reflect_pad(I, R), 0, 1)`` cropped back; ``g`` a buffer ``(C, 2R+1, 2R+1)``,
    the identity (a centred delta) until :meth:`set_kernel` or :meth:`set_from_psfs` is called."""

    kernel: torch.Tensor

    def __init__(self, channels: int = 3, radius: int = 33) -> None:
        super().__init__()
        self.radius = int(radius)
        size = 2 * self.radius + 1
        delta = torch.zeros(int(channels), size, size)
        delta[:, self.radius, self.radius] = 1.0
        self.register_buffer("kernel", delta)

    def set_kernel(self, kernel) -> None:
        """Use ``kernel`` ``(C, 2R+1, 2R+1)`` (a convolution kernel, as the depth-ensemble filter returns)."""
        value = torch.as_tensor(np.asarray(kernel), dtype=torch.float32)
        if value.shape != self.kernel.shape:
            raise ValueError(f"linear filter kernel must be {tuple(self.kernel.shape)}, got {tuple(value.shape)}")
        self.kernel.copy_(value.to(self.kernel.device))

    def set_from_psfs(self, psfs, nsr: float, grid: int = ENSEMBLE_GRID) -> None:
        """Set ``g`` to the depth-ensemble Wiener filter of ``psfs`` ``(N, C, K, K)`` with ``nsr``."""
        if isinstance(psfs, torch.Tensor):
            psfs = psfs.detach().cpu().numpy()
        self.set_kernel(depth_ensemble_wiener_kernel(psfs, nsr, radius=self.radius, grid=grid))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        r = self.radius
        if r >= min(image.shape[-2:]):
            raise EdofprojError(
                f"the network's linear filter mirrors each image by its radius, net.linear_radius={r} px, so it needs "
                f"images of at least {r + 1}x{r + 1} px, got {image.shape[-2]}x{image.shape[-1]} (height x width): "
                f"give larger images (a trained run's radius is fixed: to evaluate, a larger evaluation.image_size or "
                f"--images of at least {r + 1} px a side; to train a new run, larger data.crop or a smaller "
                f"net.linear_radius)"
            )
        padded = F.pad(image, (r, r, r, r), mode="reflect")
        filtered = convolve_same(padded, self.kernel.unsqueeze(0).to(padded.dtype))
        return filtered[..., r:-r, r:-r].clamp(0.0, 1.0)


#: Longest side (px) up to which :func:`gaussian_blur` multiplies by blur matrices; beyond it the
#: matrices' ``H + W`` products per pixel cost more than the separable convolution's taps.
MATRIX_BLUR_MAX_PX = 1024


def gaussian_window(sigma_px: float) -> torch.Tensor:
    """The normalized Gaussian taps ``w_k ~ exp(-k^2 / (2 sigma^2))``, ``|k| <= ceil(3 sigma)``, float64."""
    radius = max(1, math.ceil(3 * sigma_px))
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    window = torch.exp(-0.5 * (x / sigma_px) ** 2)
    return window / window.sum()


@functools.lru_cache(maxsize=32)
def gaussian_blur_matrix(size: int, sigma_px: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``(size, size)`` matrix ``M`` of the 1-D blur with :func:`gaussian_window` and a replicate
    border: ``(M v)_i = sum_k w_k v_clamp(i + k, 0, size - 1)`` (the border taps fold onto the
    first and last samples), so each row sums to 1. Cached, so built outside inference mode whatever the
    caller's: an inference tensor in the cache would refuse every later use of the blur under autograd
    (a network scored, then trained, in one process)."""
    with torch.inference_mode(False):
        window = gaussian_window(sigma_px)
        radius = (len(window) - 1) // 2
        source = (torch.arange(size)[:, None] + torch.arange(-radius, radius + 1)[None]).clamp(0, size - 1)
        matrix = torch.zeros(size, size, dtype=torch.float64)
        matrix.scatter_add_(1, source, window.expand(size, -1).contiguous())
        return matrix.to(device=device, dtype=dtype)


def gaussian_blur(image: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Separable normalized Gaussian blur (:func:`gaussian_window`, replicate border) of ``(B, C, H, W)``:
    :func:`blur_by_matrices` (far faster on CPUs than a 1-channel convolution) up to
    :data:`MATRIX_BLUR_MAX_PX`, :func:`blur_by_convolutions` beyond it and while tracing or exporting
    (where a matrix would fix the image size). The two agree to float rounding."""
    if max(image.shape[-2:]) <= MATRIX_BLUR_MAX_PX and not (torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()):
        return blur_by_matrices(image, sigma_px)
    return blur_by_convolutions(image, sigma_px)


def blur_by_matrices(image: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """``M_H I M_W^T`` with the blur matrices of :func:`gaussian_blur_matrix`, ``(B, C, H, W)``."""
    height, width = int(image.shape[-2]), int(image.shape[-1])
    # kept per device and dtype; a meta tensor holds no data worth keeping
    matrix = gaussian_blur_matrix.__wrapped__ if image.device.type == "meta" else gaussian_blur_matrix
    rows = matrix(height, float(sigma_px), image.dtype, str(image.device))
    cols = matrix(width, float(sigma_px), image.dtype, str(image.device))
    return torch.matmul(rows, torch.matmul(image, cols.T))


def blur_by_convolutions(image: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Two 1-D convolutions of the replicate-padded image with :func:`gaussian_window`, ``(B, C, H, W)``."""
    window = gaussian_window(sigma_px).to(device=image.device, dtype=image.dtype)
    radius = (len(window) - 1) // 2
    channels = image.shape[1]
    padded = F.pad(image, (radius, radius, radius, radius), mode="replicate")
    row_taps = window.view(1, 1, 1, -1).expand(channels, 1, 1, -1)
    col_taps = window.view(1, 1, -1, 1).expand(channels, 1, -1, 1)
    return F.conv2d(F.conv2d(padded, row_taps, groups=channels), col_taps, groups=channels)


def bounded_correction(residual: torch.Tensor, bound: float, highpass_px: float) -> torch.Tensor:
    """``c = HP_s(b_t tanh(HP_s(r) / b_t))`` (module docstring) of ``residual`` ``r`` ``(B, C, H, W)``,
    in float32: ``|c| <= bound`` at every pixel; with ``highpass_px = s > 0``, no local mean beyond a
    Gaussian of ``s`` pixels and independent of any constant added to ``r``."""
    local_mean = (lambda v: gaussian_blur(v, highpass_px)) if highpass_px > 0 else None
    return bound_around_local_mean(residual, bound, local_mean)


def bound_around_local_mean(
    residual: torch.Tensor, bound: float, local_mean: Callable[[torch.Tensor], torch.Tensor] | None
) -> torch.Tensor:
    """``c = HP(b_t tanh(HP(r) / b_t))`` with ``HP(v) = v - local_mean(v)``, in float32 whatever the
    autocast: ``|c| <= bound`` at every element, since ``b_t = bound / 2`` and a local mean (a
    normalized average, broadcast back to ``v``'s shape) of values within ``b_t`` is within ``b_t``.
    Without ``local_mean``: ``c = bound tanh(r / bound)``."""
    with torch.autocast(residual.device.type, enabled=False):
        residual = residual.float()
        if local_mean is None:
            return bound * torch.tanh(residual / bound)
        half = 0.5 * bound
        limited = half * torch.tanh((residual - local_mean(residual)) / half)
        return limited - local_mean(limited)
