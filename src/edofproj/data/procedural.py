"""Procedural training images: textured dead leaves and smooth random fields of natural colours.

Built-in photographs are few; a network trained on them alone learns their content. Procedural
images give every scale, contrast and smoothness without a single photograph:

* **smooth fields** (:func:`smooth_field_image`): Gaussian random fields with a power spectrum
  ``|F(k)|^2 ~ |k|^-beta``, ``beta ~ U[beta_min, beta_max]`` (natural images have ``beta ~ 2``;
  larger ``beta`` is smoother), one luminance field shared by the colours plus weaker, smoother
  colour fields, around a mean colour drawn from the natural palette
  (:func:`~edofproj.data.dead_leaves.natural_color_palette`);
* **textured dead leaves** (:func:`textured_dead_leaves_image`): the dead-leaves partition
  (:func:`~edofproj.data.dead_leaves.dead_leaves_labels`), each leaf of a palette colour, with a
  shading field (``beta = 3``, slow gradients across leaves) and a texture field (``beta = 1.5``,
  fine grain) whose amplitude is drawn per leaf, so flat, shaded and textured regions meet at
  sharp edges.

:class:`ProceduralSource` draws either kind with probability 1/2. Every draw comes from the
generator, so samples are reproducible like those of the other sources.
"""

from __future__ import annotations

import numpy as np
import torch

from .dead_leaves import SyntheticImageSource, dead_leaves_labels


def power_law_field(
    height: int, width: int, beta: float, generator: torch.Generator, channels: int = 1
) -> torch.Tensor:
    """Zero-mean, unit-variance Gaussian random fields ``(channels, H, W)`` with power spectrum
    ``~ |k|^-beta`` (the DC term removed): white noise filtered by ``|k|^(-beta / 2)`` in the
    Fourier domain (periodic, so a field tiles)."""
    noise = torch.randn((channels, height, width), generator=generator, dtype=torch.float64)
    ky = torch.fft.fftfreq(height, dtype=torch.float64)[:, None]
    kx = torch.fft.rfftfreq(width, dtype=torch.float64)[None, :]
    radius = torch.sqrt(kx**2 + ky**2)
    gain = torch.where(radius > 0, radius.clamp_min(1e-12) ** (-beta / 2.0), torch.zeros_like(radius))
    field = torch.fft.irfft2(torch.fft.rfft2(noise) * gain, s=(height, width))
    field = field - field.mean(dim=(-2, -1), keepdim=True)
    return (field / field.std(dim=(-2, -1), keepdim=True).clamp_min(1e-12)).float()


def _uniform(generator: torch.Generator, low: float, high: float) -> float:
    return low + (high - low) * float(torch.rand((), generator=generator, dtype=torch.float64))


def _palette_colour(palette: np.ndarray, generator: torch.Generator) -> torch.Tensor:
    return torch.tensor(palette[int(torch.randint(0, len(palette), (), generator=generator))], dtype=torch.float32)


def smooth_field_image(
    height: int,
    width: int,
    palette: np.ndarray,
    generator: torch.Generator,
    beta_range: tuple[float, float] = (2.0, 4.0),
    contrast_range: tuple[float, float] = (0.05, 0.3),
) -> torch.Tensor:
    """``(3, H, W)`` float32 in [0, 1]: ``clip(c + s L + (s / 3) C, 0, 1)`` with ``c`` a palette
    colour, ``L`` one luminance field (:func:`power_law_field`, ``beta`` drawn from
    ``beta_range``), ``C`` three colour fields one unit of ``beta`` smoother, ``s`` the contrast."""
    beta = _uniform(generator, *beta_range)
    contrast = _uniform(generator, *contrast_range)
    mean = _palette_colour(palette, generator)[:, None, None]
    luminance = power_law_field(height, width, beta, generator)
    colour = power_law_field(height, width, beta + 1.0, generator, channels=3)
    return (mean + contrast * luminance + (contrast / 3.0) * colour).clamp(0.0, 1.0)


def textured_dead_leaves_image(
    height: int,
    width: int,
    min_radius: float,
    max_radius: float,
    palette: np.ndarray,
    generator: torch.Generator,
    texture_range: tuple[float, float] = (0.0, 0.15),
    shading: float = 0.15,
) -> torch.Tensor:
    """``(3, H, W)`` float32 in [0, 1]: dead leaves of palette colours ``c_l`` times
    ``(1 + shading S + a_l T)`` -- ``S`` a smooth field (``beta = 3``), ``T`` a fine texture
    (``beta = 1.5``), ``a_l ~ U(texture_range)`` drawn per leaf."""
    labels = dead_leaves_labels(height, width, min_radius, max_radius, generator)
    used, inverse_flat = np.unique(labels, return_inverse=True)
    inverse = torch.from_numpy(inverse_flat.reshape(height, width))
    picks = torch.randint(0, len(palette), (used.size,), generator=generator)
    colours = torch.from_numpy(np.array(palette, dtype=np.float32))[picks]  # (leaves, 3)
    low, high = texture_range
    amplitude = low + (high - low) * torch.rand(used.size, generator=generator)
    shade = power_law_field(height, width, 3.0, generator)[0]
    texture = power_law_field(height, width, 1.5, generator)[0]
    gain = 1.0 + shading * shade + amplitude[inverse] * texture
    image = colours[inverse].permute(2, 0, 1) * gain
    return image.clamp(0.0, 1.0).contiguous()


class ProceduralSource(SyntheticImageSource):
    """Procedural images (module docstring): each sample is textured dead leaves or a smooth
    field with probability 1/2."""

    def one(self, crop: int, generator: torch.Generator) -> torch.Tensor:
        if float(torch.rand((), generator=generator)) < 0.5:
            return textured_dead_leaves_image(
                crop, crop, self.min_radius_px, self.max_radius_px, self.palette, generator
            )
        return smooth_field_image(crop, crop, self.palette, generator)
