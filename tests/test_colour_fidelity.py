"""Colour fidelity: CIEDE2000 against published values, per-channel SSIM, colour transforms of the
training data, the colour validation classes and the evaluation's per-image flags."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.color import lab2rgb

from edofproj.data.colour import ColourAugmentedSource, dark, empty_primary, high_key, saturate
from edofproj.data.validation import COLOUR_CLASSES, validation_images
from edofproj.evaluation.image_checks import behind_linear_filter
from edofproj.evaluation.results import BASE_METRICS, MetricsTable
from edofproj.metrics import delta_e2000, ssim, ssim_per_channel
from edofproj.reporting.image_checks import behind_linear_filter_blocks, channel_imbalance_blocks


def lab_image(lab) -> torch.Tensor:
    """A 1x1 sRGB image (1, 3, 1, 1) of a CIELAB colour."""
    rgb = lab2rgb(np.array(lab, dtype=np.float64).reshape(1, 1, 3))
    return torch.tensor(rgb, dtype=torch.float64).permute(2, 0, 1)[None]


@pytest.mark.parametrize(
    "lab1, lab2, expected",
    [  # Sharma, Wu, Dalal (2005), Table 1, pairs 7 and 14 (in the sRGB gamut)
        ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
        ((50.0, 2.5, 0.0), (50.0, 0.0, -2.5), 4.3065),
    ],
)
def test_ciede2000_matches_published_pairs(lab1, lab2, expected):
    mean, p95 = delta_e2000(lab_image(lab2), lab_image(lab1))
    assert float(mean) == pytest.approx(expected, abs=2e-3)
    assert float(p95) == pytest.approx(expected, abs=2e-3)


def test_ciede2000_mean_and_percentile_of_a_partly_changed_image():
    target = torch.full((1, 3, 20, 20), 0.5)
    pred = target.clone()
    pred[..., :2, :] = 0.6  # 10 % of the pixels differ
    mean, p95 = delta_e2000(pred, target)
    changed = float(delta_e2000(pred[..., :2, :], target[..., :2, :])[0])
    assert float(mean) == pytest.approx(0.1 * changed, rel=1e-5)
    assert float(p95) == pytest.approx(changed, rel=1e-5)  # the 95th percentile lies in the changed 10 %
    assert float(delta_e2000(target, target)[0]) == 0.0


def test_per_channel_ssim_finds_the_lost_primary_and_averages_to_ssim():
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(2, 3, 32, 32, generator=generator)
    target[:, 2] *= 0.06  # blue nearly empty
    pred = target.clone()
    pred[:, 2] *= 0.5  # its level halved
    channels = ssim_per_channel(pred, target)
    assert torch.allclose(channels[:, :2], torch.ones(2, 2))
    assert bool((channels[:, 2] < 0.95).all())
    torch.testing.assert_close(channels.mean(1), ssim(pred, target))


def test_colour_transforms_closed_forms():
    image = torch.tensor([0.2, 0.5, 0.8]).view(3, 1, 1)
    torch.testing.assert_close(saturate(image, 2.0).flatten(), torch.tensor([0.0, 0.5, 1.0]))
    torch.testing.assert_close(dark(image, 0.25).flatten(), torch.tensor([0.05, 0.125, 0.2]))
    torch.testing.assert_close(high_key(image, 0.5).flatten(), torch.tensor([0.6, 0.75, 0.9]))
    torch.testing.assert_close(empty_primary(image, 2, 0.1).flatten(), torch.tensor([0.2, 0.5, 0.08]))


class _Grey:
    crop = 8

    def sample(self, batch_size, crop=None, generator=None):
        return torch.full((batch_size, 3, 8, 8), 0.5) + 0.1 * torch.rand(batch_size, 3, 8, 8, generator=generator)


def test_colour_augmentation_is_deterministic_and_changes_the_given_share():
    source = ColourAugmentedSource(_Grey(), 0.5)
    first = [source.sample(1, 8, torch.Generator().manual_seed(i)) for i in range(200)]
    again = [source.sample(1, 8, torch.Generator().manual_seed(i)) for i in range(200)]
    assert all(torch.equal(a, b) for a, b in zip(first, again))
    plain = [_Grey().sample(1, 8, torch.Generator().manual_seed(i)) for i in range(200)]
    changed = sum(not torch.equal(a, b) for a, b in zip(first, plain))
    assert 70 <= changed <= 130  # 100 expected, binomial sd 7
    assert all(float(a.min()) >= 0 and float(a.max()) <= 1 for a in first)


def test_colour_validation_classes_have_their_trait():
    images = dict(validation_images((64, 64), names=COLOUR_CLASSES))
    assert set(images) == set(COLOUR_CLASSES)
    blue = images["colour/Minduka_near_empty_blue"][2]
    assert float(blue.max()) <= 0.08 + 1e-6
    assert float(images["colour/camera_dark"].max()) <= 0.25 + 1e-6
    assert float(images["colour/textured_high_key"].min()) >= 0.7 - 1e-6
    for image in images.values():
        assert image.shape == (3, 64, 64) and float(image.min()) >= 0 and float(image.max()) <= 1


def _table(ssim_net, ssim_linear, blue_net=1.0) -> MetricsTable:
    table = MetricsTable(("method", "depth_mm", "image"), BASE_METRICS)
    for method, values in (("doe+net", ssim_net), ("doe+ensemble", ssim_linear)):
        for image, value in values.items():
            for depth in (300.0, 800.0):
                blue = blue_net if method == "doe+net" else 1.0
                row = dict.fromkeys(BASE_METRICS, 1.0)
                row.update(ssim=value, de2000=2.0, ssim_b=blue)
                table.add(method=method, depth_mm=depth, image=image, **row)
    return table


def test_evaluation_flags_images_where_the_network_is_behind_its_linear_filter():
    table = _table({"a": 0.95, "b": 0.90}, {"a": 0.94, "b": 0.91})
    flags = {c.image: c.behind for c in behind_linear_filter(table, (300.0, 800.0))}
    assert flags == {"a": False, "b": True}
    text = str(behind_linear_filter_blocks(table, (300.0, 800.0))[0].text)
    assert "1 of 2" in text and "b (-0.0100)" in text


def test_channel_imbalance_is_reported_only_beyond_the_spread():
    table = _table({"a": 0.95}, {"a": 0.94}, blue_net=0.72)
    blocks = channel_imbalance_blocks(table, (300.0, 800.0))
    assert [row[:2] for row in blocks[0].rows] == [["doe+net", "a"]]
    calm = channel_imbalance_blocks(_table({"a": 0.95}, {"a": 0.94}, blue_net=0.96), (300.0, 800.0))
    assert "No method" in calm[0].text


def test_grating_keeps_the_channel_means_and_has_its_period():
    from edofproj.data.colour import grating

    image = torch.full((3, 96, 96), 0.4)
    image[2] = 0.7
    out = grating(image, torch.Generator().manual_seed(5))
    assert out.shape == image.shape and float(out.min()) >= 0 and float(out.max()) <= 1
    torch.testing.assert_close(out.mean(dim=(-2, -1)), image.mean(dim=(-2, -1)), atol=0.03, rtol=0)
    spectrum = torch.fft.rfft2(out - out.mean(dim=(-2, -1), keepdim=True)).abs()
    peak = spectrum.flatten(1).argmax(1)  # one sinusoid per channel: its peak is off zero frequency
    assert bool((peak > 0).all())
