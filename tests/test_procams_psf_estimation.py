"""PSF estimation (paper Eq. 13) on exact, camera-free data: patterns and their projections by
:func:`edofproj.imaging.project` (haze included), in projector output space."""

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from edofproj.errors import EdofprojError
from edofproj.imaging import project
from edofproj.procams.psf_estimation import eq13_kernel, estimate_psf, patch_boxes, window_and_floor

K = 15
C = K // 2


def lopsided_psf(energy=0.8, blur=0.8):
    """Unequal side lobes, centroid on the axis, ``energy`` in the window (the rest is haze)."""
    psf = np.zeros((3, K, K))
    psf[:, C, C], psf[:, C + 1, C + 2], psf[:, C - 2, C - 4] = 0.5, 0.2, 0.1
    psf = np.stack([gaussian_filter(channel, blur) for channel in psf])
    return psf * energy / psf.sum(axis=(-1, -2), keepdims=True)


def disc_psf(radius, energy=1.0):
    y, x = np.mgrid[-C : C + 1, -C : C + 1]
    disc = gaussian_filter((x**2 + y**2 <= radius**2).astype(float), 0.5)
    return np.repeat((disc * energy / disc.sum())[None], 3, axis=0)


def bernoulli(n, height, width, seed=0):
    return np.random.default_rng(seed).integers(0, 2, (n, height, width, 3)).astype(np.float64)


def projected(patterns, psf):
    images = torch.from_numpy(patterns.transpose(0, 3, 1, 2))
    return project(images, torch.from_numpy(psf)[None]).numpy().transpose(0, 2, 3, 1)


def l1_error(estimate, truth):
    return float(np.abs(estimate - truth).sum() / truth.sum())


def test_eq13_inverts_a_circular_convolution():
    rng = np.random.default_rng(1)
    patterns = rng.integers(0, 2, (3, 32, 40)).astype(float)
    kernel = np.zeros((32, 40))
    kernel[0, 0], kernel[1, 3], kernel[-2, -1] = 0.6, 0.3, 0.1
    captures = np.fft.ifft2(np.fft.fft2(patterns) * np.fft.fft2(kernel)).real + 0.25  # + a constant
    estimate = eq13_kernel(patterns, captures, eps_rel=1e-9)
    windowed, floor = window_and_floor(estimate, 7)
    np.testing.assert_allclose(windowed - floor, window_and_floor(kernel, 7)[0], atol=1e-6)


def test_exact_data_give_the_psf_and_its_energy():
    psf = lopsided_psf(energy=0.8)
    patterns = bernoulli(4, 72, 88)
    estimate = estimate_psf(patterns, projected(patterns, psf), window=K, eps_rel=1e-6)
    assert l1_error(estimate.psf, psf) < 1e-3
    np.testing.assert_allclose(estimate.energy_in_window, 0.8, atol=1e-3)
    assert estimate.psf[1, C + 1, C + 2] > 10 * estimate.psf[1, C - 1, C - 2]  # not flipped


def test_removing_the_outside_light_is_what_makes_it_exact():
    psf = disc_psf(4.0)
    patterns = bernoulli(4, 72, 88, seed=2)
    captures = projected(patterns, psf)
    uncorrected = l1_error(estimate_psf(patterns, captures, window=K, iterations=0, eps_rel=1e-6).psf, psf)
    corrected = l1_error(estimate_psf(patterns, captures, window=K, iterations=4, eps_rel=1e-6).psf, psf)
    assert corrected < 1e-3 < 0.1 * uncorrected


def test_noise_is_tolerated_and_the_error_is_stated():
    psf = disc_psf(3.0, energy=0.95)
    patterns = bernoulli(5, 96, 128, seed=3)
    captures = projected(patterns, psf) + np.random.default_rng(4).normal(0, 0.01, patterns.shape)
    estimate = estimate_psf(patterns, captures, window=K)
    assert l1_error(estimate.psf, psf) < 0.10
    np.testing.assert_allclose(estimate.energy_in_window, 0.95, atol=0.01)


def test_patches_see_a_spatially_varying_psf():
    """Left of x = 80 a small disc, right of it a large one: a patch whose neighbourhood (the patch
    grown by twice the window radius) sees one PSF recovers it exactly; the others still side
    with their own half."""
    small, large = disc_psf(1.5), disc_psf(5.0)
    patterns = bernoulli(4, 96, 160, seed=5)
    left = np.zeros((1, 96, 160, 1))
    left[:, :, :80] = 1.0
    captures = left * projected(patterns, small) + (1 - left) * projected(patterns, large)
    estimate = estimate_psf(patterns, captures, window=K, patch=30)
    assert len(estimate.patch_psfs) == 2 * 4
    exact = 0
    for patch_psf, (y0, y1, x0, x1) in zip(estimate.patch_psfs, estimate.patch_boxes):
        truth, other = (small, large) if (x0 + x1) / 2 < 80 else (large, small)
        if x1 + 2 * C <= 80 or x0 - 2 * C >= 80:
            assert l1_error(patch_psf, truth) < 0.01
            exact += 1
        assert l1_error(patch_psf, truth) < 0.3 * l1_error(patch_psf, other)
    assert exact == 4


def test_patch_boxes_tile_the_inner_image():
    boxes = patch_boxes(100, 130, margin=14, patch=30)
    assert boxes.shape == (2 * 3, 4)
    assert boxes[:, 0].min() >= 14 and boxes[:, 1].max() <= 100 - 14
    assert boxes[:, 2].min() >= 14 and boxes[:, 3].max() <= 130 - 14
    assert np.all(boxes[:, 1] - boxes[:, 0] == 30)
    with pytest.raises(EdofprojError, match="--patch 80 does not fit"):
        patch_boxes(100, 130, margin=14, patch=80)


def test_bad_input_raises_one_line():
    patterns = bernoulli(2, 40, 40)
    with pytest.raises(EdofprojError, match="too small for a 15 px window"):
        estimate_psf(patterns, patterns, window=15)
    with pytest.raises(EdofprojError, match="odd"):
        estimate_psf(patterns, patterns, window=4)
    with pytest.raises(EdofprojError, match=r"must both be \(n, H, W, 3\)"):
        estimate_psf(patterns, patterns[:1], window=5)
    with pytest.raises(EdofprojError, match="--patch 4 must be at least the window"):
        estimate_psf(patterns, patterns, window=5, patch=4)
