"""Li et al.'s scoring protocol (MATLAB's ssim / psnr / immse on uint8-rounded blurs in a fixed crop)
against closed forms and independent computations (scikit-image with MATLAB's settings, a brute-force
3-D Gaussian)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage
from skimage.metrics import structural_similarity

from edofproj.errors import EdofprojError
from edofproj.procams.protocol_score import (
    Crop,
    image_counts,
    matlab_ssim,
    per_channel_blur,
    score_compensations,
    to_uint8,
)


def test_ssim_of_flat_images_is_the_luminance_term_with_matlabs_double_constants():
    a, b = 40.0, 90.0
    value, ssim_map = matlab_ssim(np.full((20, 30, 3), a), np.full((20, 30, 3), b))
    c1 = (0.01 * 1.0) ** 2  # a double array's dynamic range is 1 in MATLAB, whatever the values
    assert value == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), rel=1e-12)
    assert np.ptp(ssim_map) < 1e-12


def test_ssim_2d_equals_scikit_image_with_matlabs_settings_away_from_the_border():
    rng = np.random.default_rng(0)
    ref = ndimage.gaussian_filter(rng.random((48, 40)), 2) * 255
    img = ref + rng.normal(0, 6, ref.shape)
    _, ours = matlab_ssim(img, ref)
    _, theirs = structural_similarity(
        img, ref, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, full=True
    )
    # scikit-image pads by reflection, MATLAB by replication: the maps agree 5 px inside the border
    np.testing.assert_allclose(ours[5:-5, 5:-5], theirs[5:-5, 5:-5], rtol=1e-9, atol=1e-12)


def test_ssim_of_an_rgb_array_is_matlabs_volume_ssim():
    """An H x W x 3 array: 3-D Gaussian statistics over rows, columns and colours, replicate padding,
    computed here by brute force with one full 11 x 11 x 11 kernel on an edge-padded volume."""
    rng = np.random.default_rng(1)
    ref = rng.integers(0, 256, (16, 18, 3)).astype(np.float64)
    img = np.clip(ref + rng.normal(0, 20, ref.shape), 0, 255)
    x = np.arange(-5, 6)
    g = np.exp(-(x**2) / (2 * 1.5**2))
    kernel = g[:, None, None] * g[None, :, None] * g[None, None, :]
    kernel /= kernel.sum()

    def mean(v):
        padded = np.pad(v, 5, mode="edge")
        return ndimage.correlate(padded, kernel, mode="constant")[5:-5, 5:-5, 5:-5]

    c1, c2 = 1e-4, 9e-4
    mx, my = mean(img), mean(ref)
    sx, sy, sxy = mean(img * img) - mx**2, mean(ref * ref) - my**2, mean(img * ref) - mx * my
    expected = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sx + sy + c2))
    value, ssim_map = matlab_ssim(img, ref)
    np.testing.assert_allclose(ssim_map, expected, rtol=1e-10)
    assert value == pytest.approx(expected.mean(), rel=1e-12)
    # the colours mix: not the mean of three 2-D SSIMs
    per_channel = np.mean([matlab_ssim(img[..., c], ref[..., c])[0] for c in range(3)])
    assert abs(per_channel - value) > 1e-4


def test_uint8_rounds_half_away_from_zero_and_saturates():
    values = np.array([2.5, 3.5, 0.49999, -0.5, -3.0, 254.5, 300.0, np.nan])
    np.testing.assert_array_equal(to_uint8(values), [3, 4, 0, 0, 0, 255, 255, 0])


def test_crop_conventions():
    crop = Crop.matlab([112, 74], [1105, 747])  # their V-groove crop, 1-based inclusive
    assert crop == Crop(111, 1105, 73, 747) == Crop.parse("111,1105,73,747")
    assert crop.cut(np.zeros((1140, 912))).shape == (1105 - 112 + 1, 747 - 74 + 1)
    for bad in ("1,2,3", "a,b,c,d"):
        with pytest.raises(EdofprojError, match="four integers"):
            Crop.parse(bad)
    with pytest.raises(EdofprojError, match="not inside"):
        Crop(0, 1200, 0, 10).check((1140, 912))


def test_score_with_an_identity_blur_is_closed_form():
    rng = np.random.default_rng(3)
    original = rng.integers(0, 200, (40, 30, 3)).astype(np.float64)
    comp = original.copy()
    comp[10:14, 5:10, 1] += 10.0  # 20 values off by 10, all inside the crop
    crop = Crop(2, 38, 1, 29)
    rows = score_compensations(original, [("c", comp)], lambda x: x, crop)
    normal, scored = rows
    assert (normal.name, normal.ssim, normal.psnr_db, normal.rmse) == ("normal projection", 1.0, math.inf, 0.0)
    mse = 20 * 100.0 / (36 * 28 * 3)
    peak = crop.cut(original).max()
    assert scored.rmse == pytest.approx(math.sqrt(mse), rel=1e-12)
    assert scored.psnr_db == pytest.approx(10 * math.log10(peak**2 / mse), rel=1e-12)
    assert scored.ssim == pytest.approx(matlab_ssim(crop.cut(comp), crop.cut(original))[0], rel=1e-12)


def test_every_row_uses_the_normal_projections_peak():
    """psnr(A_after, ref, min(max(A_before), max(ref))): the peak comes from the blurred original."""
    rng = np.random.default_rng(4)
    original = rng.integers(0, 256, (20, 20, 3)).astype(np.float64)
    comp = np.clip(original * 1.3, 0, 255)

    def dim(x):
        return 0.5 * x

    rows = score_compensations(original, [("c", comp)], dim)
    peak = min(float(np.max(to_uint8(0.5 * original))), float(original.max()))
    mse = float(np.mean((to_uint8(0.5 * comp) - original) ** 2))
    assert rows[1].psnr_db == pytest.approx(10 * math.log10(peak**2 / mse), rel=1e-12)


def test_per_channel_blur_and_counts():
    blur = per_channel_blur([lambda x: x, lambda x: 2 * x, lambda x: 0 * x])
    out = blur(np.ones((4, 5, 3)))
    assert out[..., 0].max() == 1 and out[..., 1].min() == 2 and out[..., 2].max() == 0
    with pytest.raises(EdofprojError, match="three"):
        per_channel_blur([lambda x: x])
    np.testing.assert_array_equal(image_counts(np.array([[[0, 257, 65535]]], dtype=np.uint16)), [[[0, 1, 255]]])
    with pytest.raises(EdofprojError, match="compensation 'c' is"):
        score_compensations(np.zeros((4, 4, 3)), [("c", np.zeros((5, 4, 3)))], lambda x: x)
