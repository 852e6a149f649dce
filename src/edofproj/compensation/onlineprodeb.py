"""OnlineProDeb, re-implemented in PyTorch: the blind CNN baseline (method ``lens+onlineprodeb``).

Reference: Y. Kageyama, D. Iwai, K. Sato, "Online Projector Deblurring Using a Convolutional
Neural Network", IEEE TVCG 28(5):2223-2233, 2022 (IEEE VR 2022). The authors published
TensorFlow/Keras *inference* code and weights (github.com/kagechan5/Online-Projector-
Deblurring-Using-a-Convolutional-Neural-Network, package ``onlineProdebnet``), grayscale
256×256 only, and no training code. This module re-implements the architecture from the
published descriptions; it is not a port of their weights, and reports call it a
re-implementation.

What is taken from the publication
----------------------------------
* Abstract: the network is "an extractor and a generator. The extractor explicitly estimates a
  defocus blur map and a luminance attenuation map. These maps are then injected into the
  middle layers of the generator network that computes the compensation image."
* Official README: three grayscale networks, ``DefocusNet``, ``LuminanceNet`` and
  ``CompensationNet``. The two extractor inputs are the concatenation (channels) of the
  previous projector image, its captured projection and the previous estimate of the map
  (zeros at the first frame); each outputs its map. ``CompensationNet`` takes the
  concatenation of the target image, the defocus map and the luminance map. Colour images:
  one pass per channel (R, G, B) through the same grayscale networks.
* The IEEE VR 2023 EDOF paper (our reference, Sec. 4.2, Table 1): the network is more complex
  than the proposed U-Net (90 ms vs 3.6 ms for 256×256 on a V100) and only supports 256×256.

What is our assumption (not published in what we could read)
------------------------------------------------------------
* Both extractors are U-Nets (``extractor_widths`` channels per scale, two 3×3 convolutions +
  LeakyReLU per block, 2×2 max-pooling down, 2×2 transposed convolution up) with a
  one-channel linear output.
* The generator is a full-resolution residual network: a 3×3 head on (target, defocus map,
  luminance map), ``generator_blocks`` residual blocks (3×3 conv, LeakyReLU, 3×3 conv, skip)
  of ``generator_width`` channels, the maps injected again at the middle block (concatenated,
  mixed by a 1×1 convolution), and a 3×3 tail that predicts a residual added to the target.
  The tail is zero-initialized, so the untrained network is the identity (as our U-Net).
* Our setting is a single static frame: the "previous projector image" is the target ``I``
  itself (projected uncompensated) and its captured result is ``I*``; the previous maps are
  zeros (the published first-frame input). ``forward(target, captured)`` thus has the same
  interface as :class:`edofproj.compensation.unet.CompensationUNet`.
* The original extractors were trained to estimate the maps explicitly; we have no map
  ground truth in the shared trainer, so the whole network is trained end to end through the
  compensation loss on the same simulated lens-only data as the other methods.
* Any image size: inputs are padded (replicate) to a multiple of the extractors' total
  down-sampling factor and cropped back.
"""

from __future__ import annotations

from typing import Any, Sequence, cast

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..errors import EdofprojError

METHOD_NAME = "lens+onlineprodeb"

#: Channel-width presets: ``extractor_widths``, ``generator_width``, ``generator_blocks``.
ONLINEPRODEB_PRESETS: dict[str, dict[str, Any]] = {
    "default": dict(extractor_widths=(16, 32, 64, 128), generator_width=32, generator_blocks=6),
    "fast": dict(extractor_widths=(8, 16, 32, 64), generator_width=16, generator_blocks=4),
}


def _conv_block(in_channels: int, out_channels: int, slope: float) -> nn.Sequential:
    """Two 3×3 convolutions, each followed by LeakyReLU."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, 3, padding=1),
        nn.LeakyReLU(slope),
        nn.Conv2d(out_channels, out_channels, 3, padding=1),
        nn.LeakyReLU(slope),
    )


class MapExtractorUNet(nn.Module):
    """U-Net: (projector image, captured result, previous map) → one map, full resolution.

    Input (N, 3, H, W) with H and W multiples of ``2 ** (len(widths) - 1)``; output (N, 1, H, W).
    """

    def __init__(self, widths: Sequence[int] = (16, 32, 64, 128), in_channels: int = 3, leaky_slope: float = 0.2):
        super().__init__()
        widths = [int(w) for w in widths]
        if len(widths) < 2 or min(widths) < 1:
            raise EdofprojError("OnlineProDeb extractor widths need at least two positive channel counts")
        self.encoders = nn.ModuleList()
        previous = in_channels
        for width in widths:
            self.encoders.append(_conv_block(previous, width, leaky_slope))
            previous = width
        self.upsamplers = nn.ModuleList()
        self.decoders = nn.ModuleList()
        for coarse, fine in zip(reversed(widths[1:]), reversed(widths[:-1])):
            self.upsamplers.append(nn.ConvTranspose2d(coarse, fine, 2, stride=2))
            self.decoders.append(_conv_block(2 * fine, fine, leaky_slope))
        self.head = nn.Conv2d(widths[0], 1, 1)

    @property
    def multiple(self) -> int:
        """Input sizes must be multiples of this (the total down-sampling)."""
        return 2 ** (len(self.encoders) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The map (N, 1, H, W) of an input (N, 3, H, W): encoder blocks with 2×2 max-pooling between them,
        decoder blocks on the up-sampled features concatenated with the encoder's skip at each scale, and a
        linear 1×1 head. H and W must be multiples of :attr:`multiple`."""
        skips = []
        for level, encoder in enumerate(self.encoders):
            if level > 0:
                x = F.max_pool2d(x, 2)
            x = encoder(x)
            skips.append(x)
        for upsample, decoder, skip in zip(self.upsamplers, self.decoders, reversed(skips[:-1])):
            x = decoder(torch.cat([upsample(x), skip], dim=1))
        return self.head(x)


class ResidualBlock(nn.Module):
    """``x + conv3(LeakyReLU(conv3(x)))`` at constant width."""

    def __init__(self, width: int, slope: float):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(width, width, 3, padding=1),
            nn.LeakyReLU(slope),
            nn.Conv2d(width, width, 3, padding=1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x + conv3(LeakyReLU(conv3(x)))``; shape (N, width, H, W) in and out."""
        return x + self.body(x)


class CompensationGenerator(nn.Module):
    """Full-resolution residual generator: (target, defocus map, luminance map) → projector input.

    ``out = target + tail(blocks(head([target, d, l])))`` with the maps concatenated again
    before the middle block (a 1×1 convolution mixes them in). The tail starts at zero.
    """

    def __init__(self, width: int = 32, blocks: int = 6, leaky_slope: float = 0.2):
        super().__init__()
        if width < 1 or blocks < 1:
            raise EdofprojError("OnlineProDeb generator_width and generator_blocks must be >= 1")
        self.head = nn.Sequential(nn.Conv2d(3, width, 3, padding=1), nn.LeakyReLU(leaky_slope))
        self.first = nn.Sequential(*[ResidualBlock(width, leaky_slope) for _ in range(blocks // 2)])
        self.inject = nn.Sequential(nn.Conv2d(width + 2, width, 1), nn.LeakyReLU(leaky_slope))
        self.second = nn.Sequential(*[ResidualBlock(width, leaky_slope) for _ in range(blocks - blocks // 2)])
        self.tail = nn.Conv2d(width, 1, 3, padding=1)
        nn.init.zeros_(self.tail.weight)
        nn.init.zeros_(cast(torch.Tensor, self.tail.bias))

    def forward(self, target: torch.Tensor, defocus: torch.Tensor, luminance: torch.Tensor) -> torch.Tensor:
        """The projector input ``target + tail(...)`` (N, 1, H, W) from the grayscale target and the two maps,
        each (N, 1, H, W)."""
        stacked = torch.cat([target, defocus, luminance], dim=1).contiguous(memory_format=torch.channels_last)
        features = self.first(self.head(stacked))
        features = self.second(self.inject(torch.cat([features, defocus, luminance], dim=1)))
        return target + self.tail(features)


class OnlineProDebNet(nn.Module):
    """OnlineProDeb re-implementation: ``net(target, captured) -> projector input`` (B, C, H, W).

    Each colour channel goes through the same grayscale networks (the published usage). The
    untrained network returns ``target`` exactly. See the module docstring for what follows
    the publication and what is assumed.
    """

    def __init__(
        self,
        extractor_widths: Sequence[int] = (16, 32, 64, 128),
        generator_width: int = 32,
        generator_blocks: int = 6,
        leaky_slope: float = 0.2,
    ):
        super().__init__()
        self.defocus_net = MapExtractorUNet(extractor_widths, leaky_slope=leaky_slope)
        self.luminance_net = MapExtractorUNet(extractor_widths, leaky_slope=leaky_slope)
        self.generator = CompensationGenerator(generator_width, generator_blocks, leaky_slope)
        # weights and features channels-last (NHWC): the layout oneDNN's CPU convolutions run without reordering
        self.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # torch accepts it; stubs lack it

    @classmethod
    def from_preset(cls, name: str = "default", leaky_slope: float = 0.2) -> "OnlineProDebNet":
        """The network with the widths of a named preset of :data:`ONLINEPRODEB_PRESETS` (``default`` or
        ``fast``). Raises :class:`~edofproj.errors.EdofprojError` for an unknown name."""
        if name not in ONLINEPRODEB_PRESETS:
            raise EdofprojError(f"unknown OnlineProDeb preset '{name}' (known: {', '.join(ONLINEPRODEB_PRESETS)})")
        return cls(**ONLINEPRODEB_PRESETS[name], leaky_slope=leaky_slope)

    def _pad(self, x: torch.Tensor) -> torch.Tensor:
        m = self.defocus_net.multiple
        h, w = x.shape[-2:]
        return F.pad(x, (0, (-w) % m, 0, (-h) % m), mode="replicate")

    def extract_maps(
        self,
        projected: torch.Tensor,
        captured: torch.Tensor,
        previous_maps: tuple[torch.Tensor, torch.Tensor] | None = None,
    ):
        """(defocus map, luminance map), each (N, 1, H, W), from grayscale (N, 1, H, W) inputs."""
        h, w = projected.shape[-2:]
        if previous_maps is None:
            zeros = torch.zeros_like(projected)
            previous_maps = (zeros, zeros)
        nhwc = torch.channels_last
        defocus_in = self._pad(torch.cat([projected, captured, previous_maps[0]], dim=1)).contiguous(memory_format=nhwc)
        luminance_in = self._pad(torch.cat([projected, captured, previous_maps[1]], dim=1)).contiguous(
            memory_format=nhwc
        )
        return self.defocus_net(defocus_in)[..., :h, :w], self.luminance_net(luminance_in)[..., :h, :w]

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        """The projector input (B, C, H, W) for the target ``I`` and its captured uncompensated projection
        ``I*``, both (B, C, H, W), any H and W: every channel is a grayscale image; the extractors estimate the
        defocus and luminance maps from ``(I, I*, 0)`` and the generator computes ``I + residual``. Raises
        :class:`~edofproj.errors.EdofprojError` unless both are 4-D with equal shapes."""
        if target.ndim != 4 or target.shape != captured.shape:
            raise EdofprojError(
                f"OnlineProDeb needs target and captured of equal shape (B, C, H, W), got "
                f"{tuple(target.shape)} and {tuple(captured.shape)}"
            )
        b, c, h, w = target.shape
        gray_target = target.reshape(b * c, 1, h, w)
        gray_captured = captured.reshape(b * c, 1, h, w)
        defocus, luminance = self.extract_maps(gray_target, gray_captured)
        return self.generator(gray_target, defocus, luminance).contiguous().reshape(b, c, h, w)
