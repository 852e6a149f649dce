"""Colour transforms of training and validation images: the content a handful of photographs lacks.

Projection-mapping content is full of saturated colours, dark and high-key scenes and colours
with one primary nearly empty (a yellow-green scene carries almost no blue). Each transform maps
an image ``x`` ``(3, H, W)`` in ``[0, 1]`` to another in ``[0, 1]``:

* ``saturate`` -- ``y = clamp(m + s (x - m), 0, 1)`` with ``m`` the pixel's channel mean, ``s > 1``;
* ``dark`` -- ``y = k x`` with ``0 < k < 1``;
* ``high_key`` -- ``y = 1 - k (1 - x)``;
* ``empty_primary`` -- one channel ``c``: ``y_c = k x_c`` with ``k`` small (the primary at a few
  per cent of its level);
* ``grating`` (with ``gratings=True``) -- fine periodic texture: each channel ``c`` becomes
  ``m_c + a_c sin(2 pi (u . p) / T_c + phi_c)`` around the image's channel mean ``m_c``, with a
  period ``T_c`` of 2.5-12 px, a direction, phase and amplitude of its own (clipped to [0, 1]).

:class:`ColourAugmentedSource` applies one of them, drawn at random, to a share
``data.colour_augment`` of a training source's samples; every draw comes from the sample's own
generator, so runs stay deterministic and resumable (:mod:`edofproj.training.sampling`).
"""

from __future__ import annotations

import torch

#: Transform names, in the order :class:`ColourAugmentedSource` draws them.
TRANSFORMS = ("saturate", "dark", "high_key", "empty_primary")
#: Ranges of the transforms' strength drawn uniformly during training.
SATURATION_RANGE = (1.5, 3.0)
DARK_RANGE = (0.1, 0.4)
HIGH_KEY_RANGE = (0.1, 0.4)
EMPTY_PRIMARY_RANGE = (0.0, 0.12)
GRATING_PERIOD_PX = (2.5, 12.0)


def saturate(image: torch.Tensor, factor: float) -> torch.Tensor:
    mean = image.mean(dim=-3, keepdim=True)
    return (mean + factor * (image - mean)).clamp(0.0, 1.0)


def dark(image: torch.Tensor, gain: float) -> torch.Tensor:
    return image * gain


def high_key(image: torch.Tensor, gain: float) -> torch.Tensor:
    return 1.0 - gain * (1.0 - image)


def empty_primary(image: torch.Tensor, channel: int, gain: float) -> torch.Tensor:
    out = image.clone()
    out[..., channel, :, :] = image[..., channel, :, :] * gain
    return out


def grating(image: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """Sinusoidal gratings around the image's channel means (module docstring), same shape."""
    height, width = image.shape[-2:]
    y, x = torch.meshgrid(
        torch.arange(height, dtype=image.dtype), torch.arange(width, dtype=image.dtype), indexing="ij"
    )
    channels = []
    for mean in image.mean(dim=(-2, -1)):
        period = _uniform(generator, GRATING_PERIOD_PX)
        angle, phase = (2 * torch.pi * torch.rand(2, generator=generator)).tolist()
        amplitude = float(torch.rand((), generator=generator)) * float(min(mean, 1 - mean))
        wave = torch.sin(
            (x * torch.cos(torch.tensor(angle)) + y * torch.sin(torch.tensor(angle))) * 2 * torch.pi / period + phase
        )
        channels.append(mean + amplitude * wave)
    return torch.stack(channels).clamp(0.0, 1.0)


def _uniform(generator: torch.Generator, bounds: tuple[float, float]) -> float:
    low, high = bounds
    return low + (high - low) * float(torch.rand((), generator=generator))


def random_colour_transform(image: torch.Tensor, generator: torch.Generator, gratings: bool = False) -> torch.Tensor:
    """One of :data:`TRANSFORMS` (and ``grating`` when ``gratings``), drawn uniformly, with its
    strength drawn from its range."""
    kinds = TRANSFORMS + (("grating",) if gratings else ())
    kind = kinds[int(torch.randint(len(kinds), (), generator=generator))]
    if kind == "grating":
        return grating(image, generator)
    if kind == "saturate":
        return saturate(image, _uniform(generator, SATURATION_RANGE))
    if kind == "dark":
        return dark(image, _uniform(generator, DARK_RANGE))
    if kind == "high_key":
        return high_key(image, _uniform(generator, HIGH_KEY_RANGE))
    channel = int(torch.randint(image.shape[-3], (), generator=generator))
    return empty_primary(image, channel, _uniform(generator, EMPTY_PRIMARY_RANGE))


class ColourAugmentedSource:
    """A training source whose samples get :func:`random_colour_transform` with probability
    ``probability`` (one uniform draw per sample, after the sample itself); ``gratings`` adds the
    grating to the transforms drawn from (``data.colour_gratings``)."""

    def __init__(self, source, probability: float, gratings: bool = False) -> None:
        self.source = source
        self.probability = float(probability)
        self.gratings = bool(gratings)
        self.crop = getattr(source, "crop", None)

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        images = self.source.sample(batch_size, crop, generator)
        if generator is None:
            generator = getattr(self.source, "generator", None) or torch.Generator()
        out = []
        for image in images:
            if float(torch.rand((), generator=generator)) < self.probability:
                image = random_colour_transform(image, generator, self.gratings)
            out.append(image)
        return torch.stack(out)
