"""The protocol's per-pixel kernels (Li et al.'s scaleGauss, their interpolation between dots, their blur)
checked against independent computations: the MATLAB placement written out, brute-force per-pixel sums,
and a known synthetic kernel field recovered everywhere."""

from __future__ import annotations

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.lab_kernels import (
    LabKernelField,
    capture_to_projector,
    kernel_field,
    orbit_window,
    rank_kernel,
)
from edofproj.procams.psf_map import DotGrid
from edofproj.procams.structured_light import CorrespondenceMap

R = 6  # their kernel_radius: 11 x 11 windows, 21 values


def scale_gauss_reference(window: np.ndarray) -> np.ndarray:
    """Their scaleGauss written out as their loops read (1-based indices shifted to 0-based), then
    normalized: the independent version the library is checked against."""
    distinct = np.unique(window.ravel())[::-1]
    select = (1 + R) * R // 2
    fill = np.zeros(select)
    fill[: min(select, len(distinct))] = distinct[:select]
    out = np.zeros((2 * R - 1, 2 * R - 1))
    c = R - 1
    k = 0
    for i in range(R):
        for j in range(i + 1):
            for a, b in ((c + i, c + j), (c + i, c - j), (c - i, c + j), (c - i, c - j)):
                out[a, b] = fill[k]
            for a, b in ((c + j, c + i), (c + j, c - i), (c - j, c + i), (c - j, c - i)):
                out[a, b] = fill[k]
            k += 1
    return out / out.sum() if out.sum() else out


def test_rank_kernel_is_their_scale_gauss_not_a_fit():
    rng = np.random.default_rng(0)
    windows = [
        rng.permutation(np.arange(121.0)).reshape(11, 11),  # 121 distinct values, scrambled
        np.where(rng.random((11, 11)) < 0.1, 200.0, 0.0),  # two levels only: a delta after ranking
        np.minimum(rng.integers(0, 40, (11, 11)).astype(float), 30.0),  # ties and a clipped top
        np.zeros((11, 11)),  # nothing seen: stays zero
    ]
    got = orbit_window(rank_kernel(np.stack(windows)))
    for window, kernel in zip(windows, got):
        np.testing.assert_allclose(kernel, scale_gauss_reference(window), atol=1e-15)
    # position does not matter: the second window's lit pixels anywhere give a centred delta
    delta = np.zeros((11, 11))
    delta[5, 5] = 1.0
    np.testing.assert_array_equal(got[1], delta)


def brute_force_blur(kernels: np.ndarray, image: np.ndarray) -> np.ndarray:
    """cal_metrics_step3's loop: each pixel the sum of its kernel times the zero-padded window."""
    H, W = image.shape
    padded = np.pad(image, 5)
    out = np.zeros((H, W))
    for y in range(H):
        for x in range(W):
            out[y, x] = np.sum(kernels[y, x] * padded[y : y + 11, x : x + 11])
    return out


def test_blur_and_adjoint_match_per_pixel_sums():
    rng = np.random.default_rng(1)
    H, W = 19, 23
    field = LabKernelField(rng.random((21, H, W)))
    kernels = orbit_window(np.moveaxis(field.orbit_values, 0, -1))
    image = rng.random((H, W))
    np.testing.assert_allclose(field.apply(image), brute_force_blur(kernels, image), rtol=1e-12)
    y = rng.random((H, W))
    assert np.isclose(np.sum(field.apply(image) * y), np.sum(image * field.adjoint(y)), rtol=1e-12)


def known_field(H: int, W: int) -> np.ndarray:
    """``(H, W, 21)`` normalized, strictly decreasing orbit values, bilinear in (y, x): a known field."""
    from edofproj.procams.lab_kernels import orbit_sizes

    sizes = orbit_sizes()
    k = np.arange(21.0)
    narrow, wide = np.exp(-k / 2.0), np.exp(-k / 9.0)
    narrow, wide = narrow / (narrow @ sizes), wide / (wide @ sizes)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    alpha = 0.1 + 0.8 * (yy / H) * (xx / W) + 0.05 * yy / H  # bilinear
    return (1 - alpha)[..., None] * narrow + alpha[..., None] * wide


def test_kernel_field_recovers_a_known_synthetic_field():
    H, W, s = 61, 50, 12
    truth = known_field(H, W)
    dots = np.zeros((H, W))
    rng = np.random.default_rng(2)
    for y in range(0, H, s):
        for x in range(0, W, s):
            window = orbit_window(truth[y, x]) * rng.uniform(2e3, 5e4)  # any brightness
            y0, x0 = max(y - 5, 0), max(x - 5, 0)
            y1, x1 = min(y + 6, H), min(x + 6, W)
            dots[y0:y1, x0:x1] = window[y0 - y + 5 : y1 - y + 5, x0 - x + 5 : x1 - x + 5]
    field = kernel_field(dots, DotGrid.covering((H, W), (s, s)))
    got = np.moveaxis(field.orbit_values, 0, -1)
    last_y, last_x = (H - 1) // s * s, (W - 1) // s * s  # 60, 48: the last row and column of dots
    inside = np.zeros((H, W), bool)
    inside[:last_y, :last_x] = True
    np.testing.assert_allclose(got[inside], truth[inside], atol=1e-12)
    # outside the complete cells only the dots keep a kernel (their script leaves the rest zero);
    # dots cut by the image's edge are ranked from what is inside, so only the interior ones are exact
    is_dot = np.zeros((H, W), bool)
    is_dot[::s, ::s] = True
    assert np.all(got[~inside & ~is_dot] == 0)
    np.testing.assert_allclose(got[last_y, 12:last_x:s], truth[last_y, 12:last_x:s], atol=1e-12)


def test_capture_to_projector_rounds_last_pixel_wins_and_subtracts_background():
    proj_x = np.array([[0.6, 1.4, 2.5], [np.nan, 1.49, 0.0]])
    proj_y = np.array([[1.0, 1.0, 1.0], [1.0, 1.2, 0.0]])
    corr = CorrespondenceMap(proj_x=proj_x, proj_y=proj_y, projector_hw=(2, 3))
    capture = np.array([[10.0, 20.0, 30.0], [40.0, 50.0, 60.0]])
    background = np.full((2, 3), 15.0)
    out = capture_to_projector(capture, corr, offset_px=(1.0, 1.0), background=background)[..., 0]
    # ceil(P - 1 - 0.5): x 0.6 -> -1 (dropped), 1.4 -> 0, 2.5 -> 1, 1.49 -> 0 (later: wins), 0.0 -> -1
    expected = np.zeros((2, 3))
    expected[0, 0] = 50.0 - 15.0
    expected[0, 1] = 30.0 - 15.0
    np.testing.assert_array_equal(out, expected)
    # negative differences clip to 0
    dim = capture_to_projector(np.full((2, 3), 5.0), corr, (1.0, 1.0), background)
    assert np.all(dim == 0)


def test_kernel_field_refuses_dots_off_the_pixel_grid():
    with pytest.raises(EdofprojError, match="whole pixels"):
        kernel_field(np.zeros((30, 30)), DotGrid((12, 12), (0.5, 0.0), 3, 3))
