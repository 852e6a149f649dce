"""The compensation U-Net of the paper (Fig. 5, Sec. 3.4).

Given the desired image ``I`` (the *target*) and what the camera would see without
compensation ``I*`` (the *captured* image, ``I`` blurred by the projector's PSF), the network
predicts the image to send to the projector:

    projector_input = I + f([I, I*])

``f`` is a U-Net with ``S = len(widths)`` scales (the paper: 7 scales, 6 down- and 6
up-sampling steps). Every scale has a block of two 3×3 convolutions, each followed by a
LeakyReLU; the decoder concatenates the encoder's features of the same scale (skip
connections). A final 1×1 convolution maps to 3 channels; it starts at zero, so an untrained
network is exactly the identity ``projector_input = I`` (residual learning from the long skip
``I -> output``).

Real-time variant (``space_to_depth = s > 1``): the input pair is first rearranged into
``s x s`` pixel blocks (``pixel_unshuffle``: 6 channels at full resolution become ``6 s^2``
channels at ``1/s`` resolution), the U-Net runs at ``1/s`` resolution, and its ``3 s^2``
output channels are rearranged back (``pixel_shuffle``) into the full-resolution residual.
Every output pixel still gets its own value; the cost of the finest scale drops by ``s^2``.

Wide-filter variant (``prefilter_bins = N > 0``): a learned rotationally symmetric linear
filter ``J = h * I`` (:class:`~edofproj.compensation.radial_filter.RadialFourierFilter`, one
real FFT pair, starts as the identity) is applied to the target first; the U-Net sees
``[I, I*, J]`` and predicts the residual on top of ``J``:

    projector_input = J + f([I, I*, J])

Safe variant (``linear_radius = R > 0``): the depth-ensemble linear filter of the DOE,
``E(I)`` (:class:`~edofproj.compensation.linear_base.LinearBase`, a fixed kernel the trainer sets),
replaces the pre-filter, and the U-Net's output becomes a bounded, mean-free correction of it:

    projector_input = E(I) + c,   |c| <= correction_bound   (:mod:`edofproj.compensation.linear_base`)

Images of any size are padded on the bottom and right to a multiple of ``s 2**(S-1)``
(replicate or reflect) and the output is cropped back. The output is *not* clamped: the
caller clamps to the projector's ``[0, 1]`` range before projecting.

Memory layout: the U-Net's weights and features are stored channels-last (NHWC), the layout in
which oneDNN's CPU convolutions (and cuDNN's tensor-core ones) run without reordering their
operands; about 1.3x faster for a training step of the ``cpu`` preset on a CPU
(``benchmarks/bench_training.py --stages``). The output is returned in the ordinary contiguous
(NCHW) layout.
"""

from __future__ import annotations

from typing import Callable, Sequence, cast

import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from .linear_base import LinearBase, bounded_correction
from .radial_filter import RadialFourierFilter

#: Named channel widths (one entry per scale, 7 scales as in the paper).
#: ``paper``: widths in the range shown in the paper's Fig. 5; ``default``: the
#: ``UNetConfig`` default (a quarter of the paper's parameters); ``fast``: few channels,
#: meant for real-time compensation on a CPU (see ``benchmarks/bench_unet.py``).
UNET_WIDTH_PRESETS: dict[str, list[int]] = {
    "paper": [32, 64, 128, 256, 256, 256, 256],
    "default": [16, 32, 64, 128, 128, 128, 128],
    "fast": [4, 8, 16, 32, 32, 32, 32],
}

DOWNSAMPLING_MODES = ("conv", "maxpool")
UPSAMPLING_MODES = ("transpose", "bilinear")
PADDING_MODES = ("replicate", "reflect")


def width_preset(name: str) -> list[int]:
    """The channel widths of preset ``name`` (a key of :data:`UNET_WIDTH_PRESETS`)."""
    if name not in UNET_WIDTH_PRESETS:
        raise EdofprojError(f"unknown U-Net width preset '{name}' (allowed: {', '.join(UNET_WIDTH_PRESETS)})")
    return list(UNET_WIDTH_PRESETS[name])


class ConvBlock(nn.Sequential):
    """Two 3×3 convolutions, each followed by ``LeakyReLU(leaky_slope)``; size preserved."""

    def __init__(self, in_channels: int, out_channels: int, leaky_slope: float) -> None:
        super().__init__(
            nn.Conv2d(in_channels, out_channels, 3, padding=1),
            nn.LeakyReLU(leaky_slope),
            nn.Conv2d(out_channels, out_channels, 3, padding=1),
            nn.LeakyReLU(leaky_slope),
        )


def _downsampling(channels: int, mode: str, leaky_slope: float) -> nn.Module:
    """Halve height and width: a learned stride-2 3×3 convolution or a 2×2 max-pool."""
    if mode == "conv":
        return nn.Sequential(nn.Conv2d(channels, channels, 3, stride=2, padding=1), nn.LeakyReLU(leaky_slope))
    return nn.MaxPool2d(2)


def _upsampling(in_channels: int, out_channels: int, mode: str) -> nn.Module:
    """Double height and width and change the channel count to ``out_channels``.

    ``transpose``: a 2×2 transposed convolution with stride 2; ``bilinear``: bilinear
    interpolation followed by a 3×3 convolution.
    """
    if mode == "transpose":
        return nn.ConvTranspose2d(in_channels, out_channels, 2, stride=2)
    return nn.Sequential(
        nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
        nn.Conv2d(in_channels, out_channels, 3, padding=1),
    )


def unet_layers(
    first: nn.Module,
    widths: Sequence[int],
    downsampling: str,
    upsampling: str,
    leaky_slope: float,
    finest_decoder: Callable[[], nn.Module] | None = None,
):
    """``(encoder, down, up, decoder)`` module lists of a U-Net with ``len(widths)`` scales.

    ``encoder[0] = first`` works at the finest scale; ``encoder[k]`` is a :class:`ConvBlock`
    after ``down[k-1]``. The decoder, coarsest first, upsamples scale ``k+1`` to scale ``k``
    (``up``), concatenates the skip and applies a :class:`ConvBlock` (``decoder``), or
    ``finest_decoder()`` at the finest scale when given (built in place, so that parameters are
    initialized in the same order either way). Run them with :func:`unet_body`."""
    encoder, down = nn.ModuleList([first]), nn.ModuleList()
    for coarse, fine in zip(widths[1:], widths[:-1]):
        down.append(_downsampling(fine, downsampling, leaky_slope))
        encoder.append(ConvBlock(fine, coarse, leaky_slope))
    up, decoder = nn.ModuleList(), nn.ModuleList()
    for scale in reversed(range(len(widths) - 1)):
        up.append(_upsampling(widths[scale + 1], widths[scale], upsampling))
        if scale == 0 and finest_decoder is not None:
            decoder.append(finest_decoder())
        else:
            decoder.append(ConvBlock(2 * widths[scale], widths[scale], leaky_slope))
    return encoder, down, up, decoder


def unet_body(x: torch.Tensor, encoder, down, up, decoder) -> torch.Tensor:
    """The U-Net pass: ``encoder[k]`` at scale ``k`` (after ``down[k-1]`` for ``k > 0``), then,
    coarsest first, ``decoder[j](concat(up[j](x), skip))`` with the encoder's output of that scale
    as ``skip``. Returns the finest scale's features."""
    skips = []
    for scale, block in enumerate(encoder):
        if scale > 0:
            x = down[scale - 1](x)
        x = block(x)
        skips.append(x)
    x = skips.pop()
    for upsample, block in zip(up, decoder):
        x = block(torch.cat([upsample(x), skips.pop()], dim=1))
    return x


class CompensationUNet(nn.Module):
    """U-Net compensation ``projector_input = target + f(concat(target, captured))``.

    Args:
        widths: channels of each scale, finest first; ``len(widths)`` scales, so
            ``len(widths) - 1`` down- and up-sampling steps.
        leaky_slope: negative slope of the LeakyReLU activations.
        in_channels: channels of ``concat(target, captured)`` (6 for two RGB images).
        out_channels: channels of the output (3, the same as ``target``).
        downsampling: ``conv`` (stride-2 convolution) or ``maxpool``.
        upsampling: ``transpose`` (transposed convolution) or ``bilinear`` (+ 3×3 conv).
        padding_mode: how images are padded to a multiple of ``2**(len(widths)-1)``:
            ``replicate`` or ``reflect``.
        space_to_depth: ``s >= 1``; with ``s > 1`` the U-Net runs at ``1/s`` resolution on
            ``s x s`` pixel blocks (pixel unshuffle / shuffle), for real-time use.
        prefilter_bins: ``N > 0`` adds the learned radial Fourier pre-filter with ``N``
            nodes (module docstring); 0 = the paper's plain U-Net.
    """

    def __init__(
        self,
        widths: Sequence[int] = tuple(UNET_WIDTH_PRESETS["default"]),
        leaky_slope: float = 0.2,
        in_channels: int = 6,
        out_channels: int = 3,
        downsampling: str = "conv",
        upsampling: str = "transpose",
        padding_mode: str = "replicate",
        space_to_depth: int = 1,
        prefilter_bins: int = 0,
        linear_radius: int = 0,
        correction_bound: float = 0.2,
        correction_highpass_px: float = 8.0,
    ) -> None:
        super().__init__()
        if int(space_to_depth) != space_to_depth or space_to_depth < 1:
            raise EdofprojError(f"U-Net space_to_depth={space_to_depth} must be an integer >= 1")
        self.space_to_depth = int(space_to_depth)
        widths = [int(w) for w in widths]
        if len(widths) < 2 or min(widths) < 1:
            raise EdofprojError(f"U-Net widths={widths} need at least two positive channel counts")
        if downsampling not in DOWNSAMPLING_MODES:
            raise EdofprojError(f"U-Net downsampling='{downsampling}' is not one of {', '.join(DOWNSAMPLING_MODES)}")
        if upsampling not in UPSAMPLING_MODES:
            raise EdofprojError(f"U-Net upsampling='{upsampling}' is not one of {', '.join(UPSAMPLING_MODES)}")
        if padding_mode not in PADDING_MODES:
            raise EdofprojError(f"U-Net padding_mode='{padding_mode}' is not one of {', '.join(PADDING_MODES)}")
        if in_channels < out_channels:
            raise EdofprojError(f"U-Net in_channels={in_channels} must hold the target's out_channels={out_channels}")
        self.widths = widths
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.padding_mode = padding_mode
        self.size_multiple = self.space_to_depth * 2 ** (len(widths) - 1)
        block = self.space_to_depth**2
        if int(prefilter_bins) != prefilter_bins or prefilter_bins < 0:
            raise EdofprojError(f"U-Net prefilter_bins={prefilter_bins} must be an integer >= 0 (0: none)")
        self.prefilter = RadialFourierFilter(out_channels, int(prefilter_bins)) if prefilter_bins else None
        if linear_radius and self.prefilter is not None:
            raise EdofprojError("a U-Net has either a learned pre-filter or a linear base filter, not both")
        self.linear_base = LinearBase(out_channels, int(linear_radius)) if linear_radius else None
        self.correction_bound = float(correction_bound)
        self.correction_highpass_px = float(correction_highpass_px)
        has_base = self.prefilter is not None or self.linear_base is not None
        unet_inputs = in_channels + (out_channels if has_base else 0)

        self.encoder, self.down, self.up, self.decoder = unet_layers(
            ConvBlock(unet_inputs * block, widths[0], leaky_slope), widths, downsampling, upsampling, leaky_slope
        )
        self.head = nn.Conv2d(widths[0], out_channels * block, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(cast(torch.Tensor, self.head.bias))
        self.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # docstring: "Memory layout"

    @classmethod
    def from_config(cls, net_cfg) -> "CompensationUNet":
        """Build from a :class:`edofproj.net_config.UNetConfig`."""
        return cls(
            widths=net_cfg.widths,
            leaky_slope=net_cfg.leaky_slope,
            downsampling=net_cfg.downsampling,
            upsampling=net_cfg.upsampling,
            padding_mode=net_cfg.padding_mode,
            space_to_depth=net_cfg.space_to_depth,
            prefilter_bins=net_cfg.prefilter_bins,
            linear_radius=net_cfg.linear_radius if net_cfg.linear_base == "ensemble" else 0,
            correction_bound=net_cfg.correction_bound,
            correction_highpass_px=net_cfg.correction_highpass_px,
        )

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        """``target + f(concat(target, captured))`` (with a pre-filter ``J``: ``J + f(concat(target,
        captured, J))``), same size as ``target``, unclamped.

        ``target`` and ``captured`` are ``(B, C, H, W)`` with ``2 * C == in_channels`` channels
        in total; any ``H, W >= 1``.
        """
        if not torch.jit.is_tracing() and (target.dim() != 4 or captured.shape != target.shape):
            raise EdofprojError(
                f"CompensationUNet needs target and captured of the same shape (B, C, H, W), got "
                f"{tuple(target.shape)} and {tuple(captured.shape)}"
            )
        height, width = target.shape[-2], target.shape[-1]
        if self.linear_base is not None:
            base = self.linear_base(target)
        else:
            base = target if self.prefilter is None else self.prefilter(target)
        has_base = self.prefilter is not None or self.linear_base is not None
        inputs = [target, captured, base] if has_base else [target, captured]
        x = torch.cat(inputs, dim=1)
        x = self._pad_to_multiple(x, height, width)
        if self.space_to_depth > 1:
            x = F.pixel_unshuffle(x, self.space_to_depth)
        x = x.contiguous(memory_format=torch.channels_last)

        residual = self.head(unet_body(x, self.encoder, self.down, self.up, self.decoder))
        if self.space_to_depth > 1:
            residual = F.pixel_shuffle(residual, self.space_to_depth)
        residual = residual[..., :height, :width].contiguous()
        if self.linear_base is not None:
            return base + bounded_correction(residual, self.correction_bound, self.correction_highpass_px)
        return base + residual

    def _pad_to_multiple(self, x: torch.Tensor, height, width) -> torch.Tensor:
        """Pad bottom/right so that height and width are multiples of ``2**(scales-1)``."""
        m = self.size_multiple
        pad_bottom = (m - height % m) % m
        pad_right = (m - width % m) % m
        if self.padding_mode == "reflect" and not torch.jit.is_tracing():
            if pad_bottom >= height or pad_right >= width:
                raise EdofprojError(
                    f"U-Net padding_mode=reflect cannot pad a {height}x{width} image to a multiple "
                    f"of {m}; use padding_mode=replicate"
                )
        return F.pad(x, (0, pad_right, 0, pad_bottom), mode=self.padding_mode)
