"""A learned, rotationally symmetric linear pre-filter applied in the Fourier domain.

A rotationally symmetric DOE (and the bare lens) has a rotationally symmetric PSF, so its
optical transfer function is real and depends only on the radial spatial frequency
``rho = |nu|`` (cycles per pixel), and so does any Wiener filter built from it. This layer
learns one such transfer function per colour channel, shared by all screen depths:

    J = F^-1[ H_c(rho) * F[pad(I)] ],   H_c(rho) = 1 + sum_k a_{c,k} Lambda_k(rho)

with ``Lambda_k`` piecewise-linear hat functions on ``bins`` nodes spread evenly over
``0 <= rho <= 1/sqrt(2)`` (the corner of the sampled frequency square). ``a = 0`` at
initialization, so the layer starts as the identity. The nodes are stored as ``a / GAIN_SCALE``: an optimizer step of size ``lr`` on the stored
values moves ``H`` by up to ``GAIN_SCALE * lr``, so gains of a few units (a typical inverse
filter) are reached within a short training run at the network's learning rate.
``pad`` replicates the border by
``margin_px`` pixels on every side before the FFT and the result is cropped back, so the
filter's circular wrap-around falls into the margin. (The padded size is not rounded up to a
fast FFT length: the padding must not depend on the frame size, or a traced TorchScript export
would only be valid at its example size.)

A U-Net has to assemble a wide inverse filter from features that its down-sampling blurs;
the defocus PSFs of the projector are up to ~30 px wide, and their inverse filters wider.
This layer gives the compensation network that wide linear filter at the cost of one real
FFT pair per frame (:class:`~edofproj.compensation.unet.CompensationUNet` option
``prefilter_bins``). Because ``H`` is a function of ``rho`` in cycles per pixel, the same
parameters apply to images of any size.
"""

from __future__ import annotations

import math
from contextlib import nullcontext

import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from ..imaging import matrix_dft

#: Largest radial frequency on a pixel grid: the corner (0.5, 0.5) cycles per pixel.
RHO_MAX = math.sqrt(0.5)
#: Stored node values are ``a / GAIN_SCALE`` (module docstring).
GAIN_SCALE = 10.0


def radial_frequency(height: int, width: int, device=None) -> torch.Tensor:
    """``rho = sqrt(fy^2 + fx^2)`` in cycles per pixel on the ``rfft2`` grid ``(height, width // 2 + 1)``.

    The frequencies are built from ``arange`` exactly as :func:`torch.fft.fftfreq` and
    :func:`torch.fft.rfftfreq` build them (``k * (1 / n)``, bit for bit), so that ONNX export
    (which has no ``fftfreq``) can hold the filter."""
    k = torch.arange(height, device=device, dtype=torch.float32)
    fy = torch.where(k < (height + 1) // 2, k, k - height) * (1.0 / height)
    fx = torch.arange(width // 2 + 1, device=device, dtype=torch.float32) * (1.0 / width)
    return torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)


def hat_interpolation(nodes: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """``sum_k nodes[..., k] Lambda_k(rho)``: piecewise-linear interpolation of ``nodes (C, N)``,
    node ``k`` at ``rho = k RHO_MAX / (N - 1)``, evaluated at ``rho (H, W)`` -> ``(C, H, W)``."""
    count = nodes.shape[-1]
    position = (rho / RHO_MAX * (count - 1)).clamp(0, count - 1)
    lower = position.floor().long().clamp(max=count - 2)
    weight = position - lower
    return nodes[:, lower] * (1 - weight) + nodes[:, lower + 1] * weight


def _autocast_on(tensor: torch.Tensor) -> bool:
    """Whether autocast is active for ``tensor``'s device type."""
    try:
        return bool(torch.is_autocast_enabled(tensor.device.type))
    except TypeError:  # torch < 2.4: no device argument
        return bool(torch.is_autocast_enabled() if tensor.is_cuda else torch.is_autocast_cpu_enabled())


class RadialFourierFilter(nn.Module):
    """``J = F^-1[(1 + sum_k a_ck Lambda_k(rho)) F[pad(I)]]`` per channel (module docstring).

    Args:
        channels: image channels ``C`` (one transfer function each).
        bins: hat-function nodes ``N >= 2`` over ``0 <= rho <= 1/sqrt(2)``.
        margin_px: border replicated on every side before the FFT (and cropped after).
    """

    def __init__(self, channels: int = 3, bins: int = 48, margin_px: int = 32) -> None:
        super().__init__()
        if int(bins) != bins or bins < 2:
            raise EdofprojError(f"radial filter bins={bins} must be an integer >= 2")
        if int(margin_px) != margin_px or margin_px < 0:
            raise EdofprojError(f"radial filter margin_px={margin_px} must be an integer >= 0")
        self.margin_px = int(margin_px)
        self.gain = nn.Parameter(torch.zeros(int(channels), int(bins)))
        self._cache: dict = {}

    def transfer_function(self, height: int, width: int) -> torch.Tensor:
        """``H_c(rho)`` on the ``rfft2`` grid of a ``height x width`` frame: ``(C, height, width // 2 + 1)``.

        Without gradients (inference) it is kept per frame size and parameter version, so a video
        stream computes it once."""
        reuse = not (torch.is_grad_enabled() or torch.jit.is_tracing() or torch.onnx.is_in_onnx_export())
        # Parameters created under torch.inference_mode have no version counter (and cannot be trained).
        version = -1 if self.gain.is_inference() else self.gain._version
        key = (height, width, self.gain.device, version)
        if reuse and key in self._cache:
            return self._cache[key]
        rho = radial_frequency(height, width, self.gain.device)
        transfer = 1 + hat_interpolation(GAIN_SCALE * self.gain, rho)
        if reuse:
            self._cache = {key: transfer}
        return transfer

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """Filter ``image (B, C, H, W)``; same shape out."""
        height, width = image.shape[-2:]
        m = self.margin_px
        padded = F.pad(image, (m, m, m, m), mode="replicate") if m else image
        ph, pw = padded.shape[-2:]
        if torch.onnx.is_in_onnx_export():
            # the DFT as matrix products (ONNX Runtime's DFT operator is several times slower), in the
            # transposed half layout (Gw, Gh // 2 + 1), where H is evaluated at rho(fx, fy) alike
            spectrum = matrix_dft.rfft2(padded, (ph, pw))
            transfer = self.transfer_function(pw, ph).to(padded.dtype).unsqueeze(-3)  # (C, 1, pw, ph // 2 + 1)
            return matrix_dft.irfft2(spectrum * transfer, (ph, pw), rows=(m, m + height), cols=(m, m + width))
        # Under bf16/fp16 autocast the FFTs still run in float32 (cuFFT has no bf16 transform, and a
        # half-precision inverse filter would lose the small gains at high frequencies).
        work = padded
        if work.dtype in (torch.bfloat16, torch.float16):
            work = work.float()
        full_precision = torch.autocast(work.device.type, enabled=False) if _autocast_on(work) else nullcontext()
        with full_precision:
            spectrum = torch.fft.rfft2(work) * self.transfer_function(ph, pw).to(work.dtype)
            filtered = torch.fft.irfft2(spectrum, s=(ph, pw)).to(image.dtype)
        return filtered[..., m : m + height, m : m + width]
