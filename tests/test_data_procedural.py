"""Procedural training images, the three-way mix and the validation set."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from edofproj.config import ConfigError, DataConfig
from edofproj.data import BUILTIN_PHOTOS, MixedSource, build_training_source, dead_leaves_image
from edofproj.data.procedural import (
    ProceduralSource,
    power_law_field,
    smooth_field_image,
    textured_dead_leaves_image,
)
from edofproj.data.validation import VALIDATION_SOURCES, validation_images


def palette():
    return np.random.default_rng(0).uniform(0.1, 0.9, (64, 3)).astype(np.float32)


@pytest.mark.parametrize("beta", [1.5, 3.0])
def test_power_law_field_has_unit_variance_and_the_spectral_slope(beta):
    field = power_law_field(128, 128, beta, torch.Generator().manual_seed(1), channels=8).double()
    assert torch.allclose(field.mean((-2, -1)), torch.zeros(8, dtype=torch.float64), atol=1e-6)
    assert torch.allclose(field.std((-2, -1)), torch.ones(8, dtype=torch.float64), atol=1e-5)
    power = (torch.fft.fft2(field).abs() ** 2).mean(0)
    k = torch.sqrt(torch.fft.fftfreq(128)[:, None] ** 2 + torch.fft.fftfreq(128)[None, :] ** 2)
    ring = (k > 0.02) & (k < 0.4)
    slope = np.polyfit(np.log(k[ring].numpy()), np.log(power[ring].numpy()), 1)[0]
    assert abs(slope + beta) < 0.15


def test_textured_leaves_without_texture_or_shading_are_the_plain_dead_leaves():
    """Same draws in the same order: with no texture and no shading, the colouring is exactly
    dead_leaves_image's; with them, the leaves vary inside but keep their colours on average."""
    plain = dead_leaves_image(64, 64, 2.0, 32.0, palette(), torch.Generator().manual_seed(4))
    flat = textured_dead_leaves_image(
        64, 64, 2.0, 32.0, palette(), torch.Generator().manual_seed(4), texture_range=(0.0, 0.0), shading=0.0
    )
    torch.testing.assert_close(flat, plain)
    textured = textured_dead_leaves_image(64, 64, 2.0, 32.0, palette(), torch.Generator().manual_seed(4))
    assert textured.shape == (3, 64, 64) and 0.0 <= float(textured.min()) and float(textured.max()) <= 1.0
    assert float((textured - plain).abs().mean()) > 0.005 and abs(float((textured - plain).mean())) < 0.02


def test_smooth_fields_and_the_source_are_deterministic_and_in_range():
    a = smooth_field_image(48, 40, palette(), torch.Generator().manual_seed(2))
    b = smooth_field_image(48, 40, palette(), torch.Generator().manual_seed(2))
    assert a.shape == (3, 48, 40) and torch.equal(a, b) and 0.0 <= float(a.min()) and float(a.max()) <= 1.0
    source = ProceduralSource(32, 1.0, 16.0, palette(), seed=0)
    first = source.sample(4, generator=torch.Generator().manual_seed(7))
    assert first.shape == (4, 3, 32, 32)
    assert torch.equal(first, source.sample(4, generator=torch.Generator().manual_seed(7)))


def test_three_way_mix_draws_each_source_at_its_fraction_and_is_validated():
    class Constant:
        crop = 4

        def __init__(self, value):
            self.value = value

        def sample(self, batch_size, crop=None, generator=None):
            return torch.full((batch_size, 3, 4, 4), self.value)

    mix = MixedSource(Constant(0.0), Constant(1.0), 0.25, procedural=Constant(2.0), procedural_fraction=0.35)
    values = mix.sample(800, generator=torch.Generator().manual_seed(0))[:, 0, 0, 0]
    shares = [float((values == v).float().mean()) for v in (0.0, 1.0, 2.0)]
    for share, expected in zip(shares, (0.4, 0.25, 0.35)):
        assert abs(share - expected) < 0.052  # binomial(800, p): 3 sigma <= 0.052
    # without a procedural share the draws are those of the dead-leaves-only mix
    old = MixedSource(Constant(0.0), Constant(1.0), 0.3).sample(50, generator=torch.Generator().manual_seed(1))
    new = MixedSource(Constant(0.0), Constant(1.0), 0.3, procedural=Constant(2.0), procedural_fraction=0.0)
    assert torch.equal(old, new.sample(50, generator=torch.Generator().manual_seed(1)))
    source = build_training_source(dataclasses.replace(DataConfig(), crop=32, procedural_fraction=0.5), seed=1)
    assert isinstance(source, MixedSource) and source.sample(3).shape == (3, 3, 32, 32)
    assert isinstance(
        build_training_source(dataclasses.replace(DataConfig(), source="procedural"), 0), ProceduralSource
    )
    with pytest.raises(ConfigError, match="sum to at most 1"):
        dataclasses.replace(DataConfig(), dead_leaves_fraction=0.6, procedural_fraction=0.6).validate()
    with pytest.raises(ConfigError, match="data.source=builtin or folder"):
        dataclasses.replace(DataConfig(), source="procedural", procedural_fraction=0.5).validate()


def test_validation_set_is_disjoint_from_training_and_test_and_loads_offline():
    photo_names = {name.split("/")[-1] for name in VALIDATION_SOURCES}
    assert not photo_names & set(BUILTIN_PHOTOS) and "chelsea" not in photo_names
    images = validation_images((64, 64))
    assert [name for name, _ in images] == sorted(VALIDATION_SOURCES)
    for _, image in images:
        assert image.shape == (3, 64, 64) and image.dtype == torch.float32
        assert 0.0 <= float(image.min()) and float(image.max()) <= 1.0
    again = dict(validation_images((64, 64), limit=3))
    assert all(torch.equal(again[name], image) for name, image in images[:3])
