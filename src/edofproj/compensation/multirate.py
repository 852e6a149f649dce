"""A multi-rate compensation network for real-time use on a CPU.

The compensation network must apply a *wide* linear filter (the inverse of defocus PSFs up to
~30 px across), a *local* linear filter (the rising high-frequency gain of that inverse) and a
*non-linear* correction (what no linear filter does: respect the projector's [0, 1] range,
adapt to the unknown depth seen in the capture). At full resolution all three are expensive on
a CPU: a Fourier filter of the whole frame costs as much as Wiener deconvolution itself, and
every full-resolution layer of a 3-channel image is memory-bound. This network works on
``s x s`` pixel blocks (``s`` = 4 by default) and splits the work by frequency:

    projector_input = I + S_s( (1 + g) (L U + B D) + W f )

* ``U``: the ``s^2`` pixels of each block of the target ``I``, per colour, for every block and a
  one-block border of replicated pixels (one stride-``s`` convolution of each padded colour
  plane, which also gives ``P``, the block means).
* ``D = F^-1[H(rho) F[P]] - P``: the wide, low-frequency part of the inverse filter, a learned
  rotationally symmetric Fourier filter
  (:class:`~edofproj.compensation.radial_filter.RadialFourierFilter`) applied to ``P``, i.e. to
  ``s^2`` times fewer samples than a full-resolution FFT.
* ``L``: the local linear part, per colour a 3x3 convolution over neighbouring blocks from the
  ``s^2`` pixels to the ``s^2`` pixels: every output pixel is a learned linear combination of
  the pixels within ``s`` to ``2s - 1`` pixels of it (a polyphase form of a ``3s x 3s`` filter,
  :func:`polyphase_taps`).
* ``B``: returns ``D`` to the pixels, per colour a 3x3 convolution over neighbouring blocks that
  starts as bilinear interpolation between block centres (and stays learnable). ``L U + B D``
  runs as *one* convolution of ``[U, H P]`` (``B D = B (H P) - B P``, and ``B P`` is linear in
  ``U``).
* ``g``: the strength of that linear correction per colour and block, a 1x1 map of ``f``. The
  inverse filter of a DOE changes with the screen depth (for the demo's DOE, the centre tap of
  the red Wiener kernel is about 4 at 300-700 mm and 0.9 at 800 mm); ``g`` lets the depth seen
  in the capture scale it.
* ``f``: the features of a U-Net whose finest scale is ``1/s``: there, the features are
  ``s x s``-patch embeddings (stride-``s`` convolutions) of ``I`` and of the capture ``I*`` plus a
  1x1 embedding of ``D``, fused by a 1x1 convolution with the upsampled coarser features; the
  :class:`~edofproj.compensation.unet.ConvBlock` scales start at ``1/(2s)``. ``W`` (1x1) maps
  ``f`` to pixel values.
* ``S_s``: places each block's ``s^2 C`` values at full resolution (a pixel shuffle, fused with
  the sum so that the full-resolution image is written once).

**Safe form** (``correction_bound = b > 0``): the linear path alone is the base and the non-linear
part a bounded correction of it,

    projector_input = I + S_s( L U + B D + c ),     c = HP( b_t tanh( HP(g (L U + B D) + W f) / b_t ) )

with ``HP(v) = v - G * mean_s2(v)``: each block's values less a Gaussian blur (sigma
``correction_highpass_px / s`` blocks, replicate border) of the block means, computed at ``1/s``
resolution, and ``b_t = b / 2`` (``b`` without the high-pass). So ``|projector_input - (I + S_s(L U +
B D))| <= b`` at every pixel for any weights, and over flat areas wider than a few ``sigma`` the
emitted level is the linear path's (as :mod:`edofproj.compensation.linear_base` does around the
full-resolution depth-ensemble filter, at ``1/s`` of its cost).

``L`` (stored divided by :data:`LOCAL_GAIN_SCALE`), ``g``, ``W`` and ``H - 1`` start at zero, so
an untrained network is the identity ``projector_input = I`` (up to FFT round-off). For a fixed
DOE, training starts ``L`` instead as the depth-ensemble Wiener filter of its PSFs
(:meth:`MultirateCompensationNet.initialize_linear_path`,
:func:`~edofproj.compensation.wiener.depth_ensemble_wiener_kernel`): the best fixed linear
compensation over the depth range, which the network then makes depth-adaptive and
range-aware. Images of any size are padded on the bottom and right (replicate) to a multiple of
``s`` at full resolution and of ``2**(S-1)`` at ``1/s`` resolution, and the output is cropped
back. The output is not clamped: the caller clamps to the projector's range. The only
full-resolution operations are three stride-``s`` convolutions, one replicate padding and the
final sum; ``edofproj bench`` measures the whole.
"""

from __future__ import annotations

from typing import Sequence, cast

import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from .linear_base import bound_around_local_mean, gaussian_blur
from .radial_filter import RadialFourierFilter
from .unet import DOWNSAMPLING_MODES, UPSAMPLING_MODES, unet_body, unet_layers

#: The local filter's stored weights are ``L / LOCAL_GAIN_SCALE``: an optimizer step of size ``lr``
#: moves a tap of ``L`` by up to ``LOCAL_GAIN_SCALE * lr``, so the taps of an inverse filter (a
#: centre gain of a few units) are reached in a short training run at the network's learning
#: rate (as :data:`~edofproj.compensation.radial_filter.GAIN_SCALE` does for ``H``). Chosen on the
#: validation split (``the realtime preset``): 10 trains well, 30 diverged.
LOCAL_GAIN_SCALE = 10.0


def bilinear_block_weights(block: int) -> torch.Tensor:
    """``(block, block, 3, 3)``: the weight of each of the 3x3 neighbouring block centres on pixel
    ``(py, px)`` of the central block under bilinear interpolation.

    Block centres sit at ``(s - 1)/2`` within their block; pixel ``p`` is at offset
    ``t = (p - (s - 1)/2) / s`` (in blocks) from its own centre, so along one axis it takes
    ``1 - |t|`` from its own block and ``|t|`` from the neighbour on the side of ``t``."""
    s = int(block)
    taps = torch.zeros(s, 3, dtype=torch.float64)
    for p in range(s):
        t = (p - (s - 1) / 2) / s
        taps[p, 1] = 1 - abs(t)
        taps[p, 2 if t > 0 else 0] += abs(t)
    return torch.einsum("yi,xj->yxij", taps, taps).float()


def unshuffle_weight(block: int) -> torch.Tensor:
    """Weights ``(s^2, 1, s, s)`` of a stride-``s`` convolution of one colour plane that equals
    ``F.pixel_unshuffle``: output channel ``s py + px`` picks pixel ``(py, px)`` of each block."""
    return torch.eye(block * block).reshape(block * block, 1, block, block)


def add_block_pixels(
    image: torch.Tensor, blocks: torch.Tensor, block: int, out: torch.Tensor | None = None
) -> torch.Tensor:
    """``image + pixel_shuffle(blocks)`` in one pass over the image: ``image (B, C, H, W)``,
    ``blocks (B, C s^2, H/s, W/s)`` with each block's pixel values in
    :func:`torch.nn.functional.pixel_shuffle`'s channel order ``(colour, row, column)``;
    the result is ``(B, C, H, W)``, written into ``out`` when given (no autograd then)."""
    b, c, height, width = image.shape
    s = int(block)
    hb, wb = height // s, width // s
    pixels = image.reshape(b, c, hb, s, wb, s)
    values = blocks.reshape(b, c, s, s, hb, wb).permute(0, 1, 4, 2, 5, 3)
    if out is not None:
        torch.add(pixels, values, out=out.view(b, c, hb, s, wb, s))
        return out
    return (pixels + values).reshape(b, c, height, width)


def polyphase_taps(kernel: torch.Tensor, block: int) -> torch.Tensor:
    """``(s^2, s^2, 3, 3)`` weights of a 3x3 convolution over neighbouring ``s x s`` blocks that
    equals the full-resolution cross-correlation ``J(y) = sum_u k(u) I(y + u)`` with the odd
    ``(2r + 1)^2`` kernel ``k`` (``r <= s``: each output pixel sees at least ``s`` pixels on
    every side through its block's neighbours). Output channel ``s py + px`` is pixel
    ``(py, px)`` of the block, input channel ``s qy + qx`` pixel ``(qy, qx)`` of a neighbour."""
    kernel = torch.as_tensor(kernel, dtype=torch.float64)
    s = int(block)
    size = kernel.shape[-1]
    if kernel.dim() != 2 or kernel.shape[0] != size or size % 2 == 0 or size > 2 * s + 1:
        raise EdofprojError(
            f"a polyphase kernel must be square, odd and at most {2 * s + 1} px for "
            f"{s}x{s} blocks, got {tuple(kernel.shape)}"
        )
    r = size // 2
    taps = torch.zeros(s, s, s, s, 3, 3, dtype=torch.float64)  # (out py, out px, in qy, in qx, dy, dx)
    for py in range(s):
        for px in range(s):
            for ky in range(size):
                for kx in range(size):
                    y, x = py + ky - r, px + kx - r  # input pixel relative to the block's origin
                    taps[py, px, y % s, x % s, y // s + 1, x // s + 1] += kernel[ky, kx]
    return taps.reshape(s * s, s * s, 3, 3)


def bounded_block_correction(values: torch.Tensor, bound: float, highpass_blocks: float) -> torch.Tensor:
    """``c = HP(b_t tanh(HP(v) / b_t))`` of per-block pixel values ``v`` ``(B, s^2, hb, wb)`` (one
    colour; module docstring), in float32: ``|c| <= bound`` everywhere
    (:func:`~edofproj.compensation.linear_base.bound_around_local_mean`). ``HP(v) = v - G * mean(v)``
    subtracts from every pixel of a block the Gaussian blur (sigma ``highpass_blocks`` blocks) of the
    block means, so a constant added to ``v`` changes nothing. ``highpass_blocks = 0``:
    ``c = bound tanh(v / bound)``."""

    def block_mean(v: torch.Tensor) -> torch.Tensor:
        return gaussian_blur(v.mean(dim=1, keepdim=True), highpass_blocks)

    return bound_around_local_mean(values, bound, block_mean if highpass_blocks > 0 else None)


class MultirateCompensationNet(nn.Module):
    """``projector_input = I + S_s((1 + g)(L U + B D) + W f)`` (module docstring).

    Args:
        widths: channels of each U-Net scale at ``1/block`` resolution, finest first.
        block: ``s >= 2``, the resolution ratio between the image and the U-Net.
        filter_bins: radial nodes of the low-resolution Fourier filter (``>= 2``).
        filter_margin_blocks: border replicated (in blocks) around ``P`` before its FFT.
        leaky_slope, downsampling, upsampling: as in
            :class:`~edofproj.compensation.unet.CompensationUNet`.
        channels: colour channels ``C`` of target and capture (3).
        correction_bound: ``b > 0``: the safe form (module docstring); 0: unbounded.
        correction_highpass_px: the high-pass's Gaussian sigma in pixels in the safe form (0: none).
    """

    #: Full-resolution inputs are read by strided convolutions and the final sum, which are
    #: fastest on contiguous (not channels-last) images; ``edofproj bench`` follows this.
    channels_last_inputs = False

    unshuffle_weight: torch.Tensor  # buffer

    def __init__(
        self,
        widths: Sequence[int] = (16, 16, 24, 32),
        block: int = 4,
        filter_bins: int = 48,
        filter_margin_blocks: int = 16,
        leaky_slope: float = 0.2,
        downsampling: str = "conv",
        upsampling: str = "transpose",
        channels: int = 3,
        correction_bound: float = 0.0,
        correction_highpass_px: float = 0.0,
    ) -> None:
        super().__init__()
        if not (correction_bound >= 0 and correction_highpass_px >= 0):
            raise EdofprojError(
                f"multirate network correction_bound={correction_bound} and correction_highpass_px="
                f"{correction_highpass_px} must be >= 0 (net.correction_bound, net.correction_highpass_px)"
            )
        self.correction_bound = float(correction_bound)
        self.correction_highpass_blocks = float(correction_highpass_px) / int(block)
        if int(block) != block or block < 2:
            raise EdofprojError(f"multirate network block={block} must be an integer >= 2 (net.block_px)")
        if int(filter_bins) != filter_bins or filter_bins < 2:
            raise EdofprojError(
                f"multirate network filter_bins={filter_bins} must be an integer >= 2 (net.filter_bins)"
            )
        widths = [int(w) for w in widths]
        if len(widths) < 2 or min(widths) < 1:
            raise EdofprojError(f"multirate network widths={widths} need at least two positive channel counts")
        if downsampling not in DOWNSAMPLING_MODES or upsampling not in UPSAMPLING_MODES:
            raise EdofprojError(
                f"multirate network: downsampling must be one of {', '.join(DOWNSAMPLING_MODES)} "
                f"and upsampling one of {', '.join(UPSAMPLING_MODES)}"
            )
        s = self.block = int(block)
        self.widths = widths
        self.channels = c = int(channels)
        self.lowres_multiple = 2 ** (len(widths) - 1)

        # U and P of every colour plane (colours ride in the batch dimension).
        self.register_buffer("unshuffle_weight", unshuffle_weight(s), persistent=False)
        self.prefilter = RadialFourierFilter(c, int(filter_bins), margin_px=int(filter_margin_blocks))
        # L (zero at start) and B (bilinear at start), one of each per colour: the PSFs, and so
        # the inverse filters, differ between colours. (One dense convolution per colour: grouped
        # convolutions are several times slower on CPUs.)
        self.local_filter = nn.ModuleList()
        self.correction_to_pixels = nn.ModuleList()
        for _ in range(c):
            local = nn.Conv2d(s * s, s * s, 3, bias=False)  # inputs are padded by one block (replicate)
            nn.init.zeros_(local.weight)
            self.local_filter.append(local)
            to_pixels = nn.Conv2d(1, s * s, 3, bias=False)
            with torch.no_grad():
                to_pixels.weight.copy_(bilinear_block_weights(s).reshape(s * s, 1, 3, 3))
            self.correction_to_pixels.append(to_pixels)

        # U-Net at 1/s resolution, and W.
        self.embed_target = nn.Conv2d(c, widths[0], s, stride=s)
        self.embed_captured = nn.Conv2d(c, widths[0], s, stride=s, bias=False)
        self.embed_correction = nn.Conv2d(c, widths[0], 1, bias=False)
        self.activation = nn.LeakyReLU(leaky_slope)
        # The finest scale (1/s) has no 3x3 convolutions: its features are the embeddings, and the
        # decoder fuses them with the upsampled coarser features by a 1x1 convolution. (3x3 blocks
        # there cost a fifth of the frame time and did not change the validation SSIM: 0.9845 with,
        # 0.9839 without; the realtime preset.)
        self.encoder, self.down, self.up, self.decoder = unet_layers(
            nn.Identity(),
            widths,
            downsampling,
            upsampling,
            leaky_slope,
            finest_decoder=lambda: nn.Sequential(nn.Conv2d(2 * widths[0], widths[0], 1), nn.LeakyReLU(leaky_slope)),
        )
        self.head = nn.Conv2d(widths[0], c * s * s, 1)  # W: pixel values, colour-major channels
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(cast(torch.Tensor, self.head.bias))
        # g: the strength of the linear correction per colour and block (zero at start)
        self.linear_gain = nn.Conv2d(widths[0], c, 1)
        nn.init.zeros_(self.linear_gain.weight)
        nn.init.zeros_(cast(torch.Tensor, self.linear_gain.bias))

    @classmethod
    def from_config(cls, net_cfg) -> "MultirateCompensationNet":
        """Build from a :class:`edofproj.net_config.MultirateConfig` (``block_px`` is the block size,
        ``filter_bins`` the filter's nodes)."""
        return cls(
            widths=net_cfg.widths,
            block=net_cfg.block_px,
            filter_bins=net_cfg.filter_bins,
            leaky_slope=net_cfg.leaky_slope,
            downsampling=net_cfg.downsampling,
            upsampling=net_cfg.upsampling,
            correction_bound=net_cfg.correction_bound,
            correction_highpass_px=net_cfg.correction_highpass_px,
        )

    def initialize_linear_path(self, kernels) -> None:
        """Start ``L`` as a known linear compensation: ``I + L U`` equals the full-resolution
        convolution with ``kernels (C, 2r+1, 2r+1)`` of the replicate-padded image (``r <= s``; e.g.
        the depth-ensemble Wiener kernel,
        :func:`~edofproj.compensation.wiener.depth_ensemble_wiener_kernel`), border included, while
        ``H = 1`` (so ``D = 0``) and ``g = 0``. Training then starts from a deconvolution instead of
        the identity."""
        kernels = torch.as_tensor(kernels, dtype=torch.float64)
        if kernels.dim() != 3 or kernels.shape[0] != self.channels:
            raise EdofprojError(
                f"initialize_linear_path needs ({self.channels}, K, K) kernels, got {tuple(kernels.shape)}"
            )
        s = self.block
        identity = polyphase_taps(F.pad(torch.ones(1, 1), (s, s, s, s)), s)
        with torch.no_grad():
            for local, kernel in zip(self.local_filter, kernels):
                weight = cast(nn.Conv2d, local).weight
                taps = polyphase_taps(kernel.flip(-2, -1), s) - identity  # convolution -> correlation
                weight.copy_((taps / LOCAL_GAIN_SCALE).to(weight.dtype))

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        """``I + S_s((1 + g)(L U + B D) + W f)`` (safe form: ``I + S_s(L U + B D + c)``), same size as
        ``target`` ``(B, C, H, W)``, unclamped."""
        if not torch.jit.is_tracing() and (
            target.dim() != 4 or captured.shape != target.shape or target.shape[1] != self.channels
        ):
            raise EdofprojError(
                f"MultirateCompensationNet needs target and captured of the same shape (B, {self.channels}, H, W), "
                f"got {tuple(target.shape)} and {tuple(captured.shape)}"
            )
        height, width = target.shape[-2], target.shape[-1]
        s, c = self.block, self.channels
        n = s * s
        lowres = torch.channels_last
        full_target = _pad_bottom_right(target, s)
        full_captured = _pad_bottom_right(captured, s)

        b, hb, wb = full_target.shape[0], full_target.shape[-2] // s, full_target.shape[-1] // s
        planes = full_target.contiguous().view(b * c, 1, full_target.shape[-2], full_target.shape[-1])
        # U of every block and of a one-block border (pixels replicated), and P as channel s^2
        pixels = F.conv2d(F.pad(planes, (s, s, s, s), mode="replicate"), self.unshuffle_weight, stride=s)
        exported = torch.onnx.is_in_onnx_export()  # in-place writes would become ONNX scatters
        if exported:
            mean = pixels.mean(dim=1, keepdim=True)
            means = mean[:, 0, 1:-1, 1:-1].reshape(b, c, hb, wb)  # P
            correction = self.prefilter(means) - means  # D
            blocks = torch.cat([pixels, mean + _pad_one_block(correction).view(b * c, 1, hb + 2, wb + 2)], dim=1)
        else:
            # (B C, s^2 + 1, hb + 2, wb + 2), channels-last for the convolutions over blocks (one
            # 17-channel convolution would do the same, but oneDNN runs it several times slower)
            blocks = torch.empty(
                (b * c, n + 1, hb + 2, wb + 2), dtype=pixels.dtype, device=pixels.device, memory_format=lowres
            )
            blocks[:, :n] = pixels
            blocks[:, n:] = pixels.mean(dim=1, keepdim=True)
            means = blocks[:, n, 1:-1, 1:-1].reshape(b, c, hb, wb)  # P
            correction = (self.prefilter(means) - means).contiguous()  # D
            # channel s^2 becomes P + D = H P (D replicated over the border blocks)
            blocks[:, n].add_(_pad_one_block(correction).view(b * c, hb + 2, wb + 2))

        colour_blocks = blocks.view(b, c, n + 1, hb + 2, wb + 2)
        linears = [
            F.conv2d(colour_blocks[:, i], self._linear_weight(i).contiguous(memory_format=lowres)) for i in range(c)
        ]
        features = _full_resolution_conv(self.embed_target, full_target)
        features = (
            features + _full_resolution_conv(self.embed_captured, full_captured) + self.embed_correction(correction)
        )
        features = self.activation(features)
        features = self._unet(features.contiguous(memory_format=lowres)).contiguous(memory_format=lowres)
        inference = not (torch.is_grad_enabled() or torch.jit.is_tracing() or exported)
        # the safe form with its high-pass, at inference in float32: c = h HP(tanh(HP(r / h))) with
        # h = b/2 (HP is linear), r / h from the head and gain scaled by 1/h, each pass in place
        fused_safe = (
            inference
            and self.correction_bound > 0
            and self.correction_highpass_blocks > 0
            and features.dtype == torch.float32
        )
        scale = 2.0 / self.correction_bound if fused_safe else 1.0
        shared = F.conv2d(features, self.head.weight * scale, cast(torch.Tensor, self.head.bias) * scale)
        gain = self.linear_gain(features) * scale if fused_safe else self.linear_gain(features)
        per_colour = []
        if fused_safe:
            linears = self._safe_values_in_place(linears, shared, gain)
        for i, linear in enumerate(linears):
            if fused_safe:
                values = linear
            elif self.correction_bound > 0:  # safe form: L U + B D + c, |c| <= b
                raw = torch.addcmul(shared[:, i * n : (i + 1) * n], linear, gain[:, i : i + 1])
                bounded = bounded_block_correction(raw, self.correction_bound, self.correction_highpass_blocks)
                values = linear + bounded.to(linear.dtype)
            else:
                values = torch.addcmul(shared[:, i * n : (i + 1) * n], linear, 1 + gain[:, i : i + 1])  # one pass
            per_colour.append(values)
        if exported:  # ONNX DepthToSpace
            output = full_target + F.pixel_shuffle(torch.cat(per_colour, dim=1), s)
        elif not inference:
            output = add_block_pixels(full_target, torch.stack(per_colour, dim=1).view(b, c * n, hb, wb), s)
        else:  # each colour plane written straight into the output (no stacked copy)
            output = torch.empty(full_target.shape, dtype=full_target.dtype, device=full_target.device)
            for i, values in enumerate(per_colour):
                add_block_pixels(full_target[:, i : i + 1], values, s, out=output[:, i : i + 1])
        return output[..., :height, :width]

    def _safe_values_in_place(
        self, linears: list[torch.Tensor], scaled_shared: torch.Tensor, scaled_gain: torch.Tensor
    ) -> list[torch.Tensor]:
        """The safe form's block values ``L U + B D + h HP(tanh(HP(r / h)))`` of every colour at
        inference (the arithmetic of :func:`bounded_block_correction`, ``h = b / 2``), from the linear
        path's values and the head and gain already scaled by ``1 / h``: ``r / h = W f / h + (L U + B D)
        g / h``. Each pass runs in place, and one blur serves the three colours' block means."""
        n = self.block * self.block
        residuals = [
            torch.addcmul(scaled_shared[:, i * n : (i + 1) * n], linear, scaled_gain[:, i : i + 1])
            for i, linear in enumerate(linears)
        ]
        for outer in (False, True):  # HP, tanh, then HP again
            means = torch.cat([r.mean(dim=1, keepdim=True) for r in residuals], dim=1)
            local_means = gaussian_blur(means, self.correction_highpass_blocks)
            for i, residual in enumerate(residuals):
                residual.sub_(local_means[:, i : i + 1])
                if not outer:
                    residual.tanh_()
        half = 0.5 * self.correction_bound
        return [linear.add_(residual, alpha=half) for linear, residual in zip(linears, residuals)]

    def _linear_weight(self, colour: int) -> torch.Tensor:
        """``(s^2, s^2 + 1, 3, 3)``: ``L U + B D`` as one convolution of the ``s^2`` pixels and ``H P``
        of each block and its 8 neighbours: ``B D = B (H P) - B P``, and ``B P`` is linear in the
        pixels (``P`` is their mean), so it joins ``L`` on them."""
        n = self.block * self.block
        local = LOCAL_GAIN_SCALE * cast(nn.Conv2d, self.local_filter[colour]).weight  # scale the taps, not the image
        to_pixels = cast(nn.Conv2d, self.correction_to_pixels[colour]).weight  # (s^2, 1, 3, 3)
        return torch.cat([local - to_pixels / n, to_pixels], dim=1)

    def _unet(self, x: torch.Tensor) -> torch.Tensor:
        """The U-Net body at ``1/s`` resolution (input padded to a multiple of ``2**(S-1)``, output cropped)."""
        height, width = x.shape[-2], x.shape[-1]
        x = unet_body(_pad_bottom_right(x, self.lowres_multiple), self.encoder, self.down, self.up, self.decoder)
        return x[..., :height, :width]


def _full_resolution_conv(conv: nn.Conv2d, image: torch.Tensor) -> torch.Tensor:
    """``conv(image)`` with the weights in the image's memory format: a contiguous image is then not
    copied to channels-last first (the copy of a full-resolution frame costs more than the
    stride-``s`` convolution itself)."""
    layout = torch.channels_last if image.is_contiguous(memory_format=torch.channels_last) else torch.contiguous_format
    return F.conv2d(image, conv.weight.contiguous(memory_format=layout), conv.bias, conv.stride)


def _pad_one_block(x: torch.Tensor) -> torch.Tensor:
    """Replicate one sample on every side."""
    return F.pad(x, (1, 1, 1, 1), mode="replicate")


def _pad_bottom_right(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Replicate-pad bottom/right to a multiple of ``multiple`` (no copy when already one)."""
    pad_bottom = (multiple - x.shape[-2] % multiple) % multiple
    pad_right = (multiple - x.shape[-1] % multiple) % multiple
    if not (pad_bottom or pad_right or torch.jit.is_tracing()):
        return x
    return F.pad(x, (0, pad_right, 0, pad_bottom), mode="replicate")
