"""Dead leaves: exact radius law, coverage after one layer, Matheron's two-point law, colours, seeding."""

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.stats
import torch

from edofproj.data import (
    dead_leaves_image,
    dead_leaves_labels,
    disks_per_covering_layer,
    natural_color_palette,
    paint_front_most,
    sample_dead_leaves_disks,
)
from edofproj.errors import EdofprojError


def radius_density(r, rmin, rmax):
    """The stationary model's radius density p(r) = 2 r^-3 / (rmin^-2 - rmax^-2)."""
    return 2 * r**-3.0 / (rmin**-2 - rmax**-2)


def test_disks_touching_the_image_follow_p_r_times_box_area():
    # a disk of radius r can reach the image iff its centre lies in a box of area (W-1+2r)(H-1+2r)
    rmin, rmax, height, width = 1.0, 40.0, 30, 50
    radii, cx, cy = sample_dead_leaves_disks(20000, height, width, rmin, rmax, torch.Generator().manual_seed(0))
    weight = lambda r: radius_density(r, rmin, rmax) * (width - 1 + 2 * r) * (height - 1 + 2 * r)  # noqa: E731
    total = scipy.integrate.quad(weight, rmin, rmax, limit=200)[0]
    cdf = np.vectorize(lambda r: scipy.integrate.quad(weight, rmin, min(max(r, rmin), rmax), limit=200)[0] / total)
    assert scipy.stats.kstest(radii, cdf).pvalue > 1e-3
    assert np.all((cx >= -radii) & (cx <= width - 1 + radii) & (cy >= -radii) & (cy <= height - 1 + radii))
    # centres are uniform across the box: the normalised position has mean 1/2 and variance 1/12
    t = (cx + radii) / (width - 1 + 2 * radii)
    assert abs(t.mean() - 0.5) < 0.01 and abs(t.var() - 1 / 12) < 0.003


def test_one_covering_layer_leaves_a_fraction_1_over_e_uncovered():
    # each disk covers a given pixel with probability pi E[r^2] / E[A(r)] = 1 / n_layer, so after
    # n_layer disks a pixel is uncovered with probability (1 - 1/n_layer)^n_layer ~ exp(-1)
    rmin, rmax, size = 1.0, 32.0, 96
    n_layer = disks_per_covering_layer(size, size, rmin, rmax)
    generator = torch.Generator().manual_seed(1)
    fractions = []
    for _ in range(8):
        labels = np.full((size, size), np.iinfo(np.int64).max, dtype=np.int64)
        paint_front_most(labels, *sample_dead_leaves_disks(int(round(n_layer)), size, size, rmin, rmax, generator), 0)
        fractions.append(np.mean(labels == np.iinfo(np.int64).max))
    assert np.mean(fractions) == pytest.approx((1 - 1 / round(n_layer)) ** round(n_layer), abs=0.03)


def test_paint_front_most_covers_exactly_the_pixel_centres_inside_each_disk():
    labels = np.full((20, 30), 99, dtype=np.int64)
    radii, cx, cy = np.array([4.3, 2.0]), np.array([10.2, 12.0]), np.array([9.7, 9.0])
    paint_front_most(labels, radii, cx, cy, first_index=0)
    y, x = np.mgrid[:20, :30]
    in0 = (x - 10.2) ** 2 + (y - 9.7) ** 2 <= 4.3**2
    in1 = (x - 12.0) ** 2 + (y - 9.0) ** 2 <= 2.0**2
    expected = np.where(in0, 0, np.where(in1, 1, 99))  # disk 0 lies in front of disk 1
    np.testing.assert_array_equal(labels, expected)


def same_leaf_probability(d, rmin, rmax):
    """Matheron: P(two points at distance d see the same leaf) = E|D ∩ D+d| / E|D ∪ D+d|."""

    def lens(r):
        return 2 * r * r * math.acos(d / (2 * r)) - d / 2 * math.sqrt(4 * r * r - d * d)

    overlap = scipy.integrate.quad(
        lambda r: lens(r) * radius_density(r, rmin, rmax), max(rmin, d / 2), rmax, limit=200
    )[0]
    area = math.pi * scipy.integrate.quad(lambda r: r * r * radius_density(r, rmin, rmax), rmin, rmax)[0]
    return overlap / (2 * area - overlap)


def test_two_point_statistics_match_matheron_formula():
    rmin, rmax, size, distances = 1.0, 24.0, 128, (1, 2, 4, 8, 16)
    generator = torch.Generator().manual_seed(0)
    estimates = []
    for _ in range(16):
        labels = dead_leaves_labels(size, size, rmin, rmax, generator)
        assert labels.max() < np.iinfo(np.int64).max  # every pixel is covered
        estimates.append(
            [
                np.mean(
                    np.concatenate([(labels[:, d:] == labels[:, :-d]).ravel(), (labels[d:] == labels[:-d]).ravel()])
                )
                for d in distances
            ]
        )
    measured = np.mean(estimates, axis=0)
    expected = [same_leaf_probability(d, rmin, rmax) for d in distances]
    np.testing.assert_allclose(measured, expected, atol=0.04)


def test_images_use_one_palette_colour_per_leaf_and_are_reproducible():
    palette = natural_color_palette()
    assert palette.shape[1] == 3 and palette.min() >= 0 and palette.max() <= 1
    image = dead_leaves_image(48, 64, 2.0, 30.0, palette, torch.Generator().manual_seed(3))
    again = dead_leaves_image(48, 64, 2.0, 30.0, palette, torch.Generator().manual_seed(3))
    other = dead_leaves_image(48, 64, 2.0, 30.0, palette, torch.Generator().manual_seed(4))
    assert image.shape == (3, 48, 64) and image.dtype == torch.float32
    assert torch.equal(image, again) and not torch.equal(image, other)
    labels = dead_leaves_labels(48, 64, 2.0, 30.0, torch.Generator().manual_seed(3))
    pixels = image.permute(1, 2, 0).numpy()
    for leaf in np.unique(labels)[:50]:
        colours = pixels[labels == leaf]
        assert np.all(colours == colours[0])
    palette_rows = {tuple(c) for c in palette.tolist()}
    assert all(tuple(c) in palette_rows for c in np.unique(pixels.reshape(-1, 3), axis=0).tolist())


def test_invalid_radii_are_refused():
    with pytest.raises(EdofprojError, match="0 < min <= max"):
        dead_leaves_labels(8, 8, 4.0, 2.0, torch.Generator())
