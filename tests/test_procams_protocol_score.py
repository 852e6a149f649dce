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


def test_counts_and_shapes():
    np.testing.assert_array_equal(image_counts(np.array([[[0, 257, 65535]]], dtype=np.uint16)), [[[0, 1, 255]]])
    with pytest.raises(EdofprojError, match="compensation 'c' is"):
        score_compensations(np.zeros((4, 4, 3)), [("c", np.zeros((5, 4, 3)))], lambda x: x)


def smooth_field(H: int, W: int, seed: int = 5):
    """Normalized, decreasing kernels that widen across the image (a lab field with known structure)."""
    from edofproj.procams.lab_kernels import LabKernelField, orbit_sizes

    k = np.arange(21.0)
    xx = np.linspace(0, 1, W)[None, :, None]
    values = np.exp(-k / (1.0 + 4.0 * xx)) * np.ones((H, 1, 1))
    values /= (values @ orbit_sizes())[..., None]
    return LabKernelField(np.ascontiguousarray(np.moveaxis(values, -1, 0)))


def test_optimum_reaches_an_achievable_target_and_beats_the_original():
    from edofproj.procams.protocol_score import lab_protocol_blur, least_squares_optimum

    H, W = 40, 44
    field = smooth_field(H, W)
    blur = lab_protocol_blur([field] * 3, "test")
    rng = np.random.default_rng(6)
    # the adjoint is the transpose, and the bound is above the norm (power iteration)
    x, y = (rng.random((H, W)) for _ in range(2))
    assert np.isclose(np.sum(field.apply(x) * y), np.sum(x * field.adjoint(y)), rtol=1e-12)
    v = rng.random((H, W))
    for _ in range(50):
        v = field.adjoint(field.apply(v))
        v /= np.linalg.norm(v)
    assert np.sqrt(np.sum(field.adjoint(field.apply(v)) * v)) <= field.norm_bound() * (1 + 1e-9)
    # a target inside the achievable set: A x* with x* inside the box
    truth = 255 * rng.uniform(0.1, 0.9, (H, W, 3))
    target = blur.blur(truth)
    crop = Crop(6, 34, 6, 38)
    optimum, tail = least_squares_optimum(target, blur, crop, iterations=300)
    assert 0 <= tail < 0.01
    residual = crop.cut(blur.blur(optimum) - target)
    assert 10 * np.log10(255**2 / np.mean(residual**2)) > 40
    # on a real image it beats projecting the original (the first iterate)
    original = 255 * ndimage.gaussian_filter(rng.random((H, W, 3)), (1.5, 1.5, 0))
    original = np.clip((original - original.min()) * 3, 0, 255)
    rows = score_compensations(
        original, [("opt", to_uint8(least_squares_optimum(original, blur, crop, 100)[0]))], blur.blur, crop
    )
    assert rows[1].psnr_db > rows[0].psnr_db + 1 and rows[1].rmse < rows[0].rmse
