"""The field-varying blur operator (imaging.field_varying.FieldVaryingBlur) against a dense
per-pixel sum, its adjoint by the dot-product test, and its low-rank truncation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.field_varying import FieldVaryingBlur, low_rank_kernels


def dense_blur(image: np.ndarray, kernels: np.ndarray, cy, cx) -> np.ndarray:
    """out(y) = sum_x' I(x') p(y - x'; x') with p(.; x') the bilinear (np.interp per axis, clamped)
    interpolation of the node kernels at x': a per-pixel loop, no FFT, no low rank."""
    C, H, W = image.shape
    K = kernels.shape[-1]
    m = K // 2
    out = np.zeros((C, H + 2 * m, W + 2 * m))
    eye_y, eye_x = np.eye(len(cy)), np.eye(len(cx))
    for y in range(H):
        wy = np.array([np.interp(y, cy, e) for e in eye_y])
        for x in range(W):
            wx = np.array([np.interp(x, cx, e) for e in eye_x])
            p = np.einsum("i,j,ijckl->ckl", wy, wx, kernels)  # (C or 1, K, K)
            out[:, y : y + K, x : x + K] += image[:, y, x, None, None] * p
    return out[:, m : m + H, m : m + W]


def gaussian(sigma_x: float, sigma_y: float, radius: int) -> np.ndarray:
    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    k = np.exp(-0.5 * (x**2 / sigma_x**2 + y**2 / sigma_y**2))
    return k / k.sum()


@pytest.mark.parametrize("channels", [1, 3])
def test_blur_equals_the_dense_per_pixel_sum(channels):
    rng = np.random.default_rng(1)
    H, W, K = 23, 31, 7
    cy, cx = np.array([2.0, 11.0, 20.0]), np.array([0.0, 9.5, 18.0, 30.0])
    kernels = rng.random((3, 4, channels, K, K))
    kernels /= kernels.sum(axis=(-1, -2), keepdims=True)
    image = rng.random((3, H, W))
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W))
    got = op(torch.from_numpy(image)[None])[0].numpy()
    np.testing.assert_allclose(got, dense_blur(image, kernels, cy, cx), atol=1e-12)
    assert op.rank == 12  # random kernels: full rank, one per node


@pytest.mark.parametrize("tolerance", [0.0, 1e-2])
def test_adjoint_passes_the_dot_product_test(tolerance):
    rng = np.random.default_rng(2)
    H, W = 40, 52
    cy, cx = np.linspace(0, H - 1, 4), np.linspace(0, W - 1, 5)
    kernels = np.stack(
        [[[gaussian(0.6 + 0.3 * i, 0.8 + 0.4 * j, 6)] * 3 for j in range(5)] for i in range(4)]
    ) + 0.01 * rng.random((4, 5, 3, 13, 13))
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W), rank_tolerance=tolerance)
    x = torch.from_numpy(rng.standard_normal((2, 3, H, W)))
    y = torch.from_numpy(rng.standard_normal((2, 3, H, W)))
    left, right = float((op(x) * y).sum()), float((x * op.adjoint(y)).sum())
    assert abs(left - right) <= 1e-10 * abs(left)


def test_low_rank_truncation_keeps_the_error_within_the_tolerance():
    # Gaussians whose widths vary smoothly: a few basis kernels carry them
    widths = np.linspace(0.7, 2.5, 40)
    kernels = torch.from_numpy(np.stack([gaussian(s, 1.3 * s, 10) for s in widths]))
    for tolerance in (1e-2, 1e-3, 1e-5):
        basis, coefficients = low_rank_kernels(kernels, tolerance)
        approx = torch.einsum("nm,mkl->nkl", coefficients, basis)
        error = float(torch.linalg.norm(approx - kernels) / torch.linalg.norm(kernels))
        assert error <= tolerance
        assert basis.shape[0] < len(widths)
    exact_basis, exact_coefficients = low_rank_kernels(kernels, 0.0)
    approx = torch.einsum("nm,mkl->nkl", exact_coefficients, exact_basis)
    assert float((approx - kernels).abs().max()) < 1e-12


def test_constant_kernels_are_the_plain_convolution():
    from scipy.signal import fftconvolve

    rng = np.random.default_rng(3)
    k = gaussian(1.2, 2.0, 7)
    op = FieldVaryingBlur(
        torch.from_numpy(np.broadcast_to(k, (3, 3, 1, 15, 15)).copy()), [0, 20, 40], [0, 30, 60], (41, 61)
    )
    image = rng.random((2, 41, 61))
    got = op(torch.from_numpy(image)[None])[0].numpy()
    assert op.rank == 1
    np.testing.assert_allclose(got, np.stack([fftconvolve(c, k, mode="same") for c in image]), atol=1e-12)


def test_bad_shapes_are_refused_in_one_line():
    k = torch.ones(2, 2, 1, 3, 3) / 9
    with pytest.raises(EdofprojError, match="K odd"):
        FieldVaryingBlur(torch.ones(2, 2, 1, 4, 4), [0, 9], [0, 9], (10, 10))
    with pytest.raises(EdofprojError, match="centres"):
        FieldVaryingBlur(k, [0, 5, 9], [0, 9], (10, 10))
    op = FieldVaryingBlur(k, [0, 9], [0, 9], (10, 10))
    with pytest.raises(EdofprojError, match="set up for"):
        op(torch.ones(1, 1, 10, 11))


def test_the_randomized_basis_of_many_kernels_keeps_the_tolerance():
    # 5000 kernels of 31 x 31 taps (past the exact decomposition's size): Gaussians of varied widths and angles
    rng = np.random.default_rng(4)
    y, x = np.mgrid[-15:16, -15:16]
    kernels = []
    for _ in range(5000):
        a, b, t = rng.uniform(0.5, 3.0), rng.uniform(0.5, 3.0), rng.uniform(0, np.pi)
        c, s = np.cos(t), np.sin(t)
        u, v = c * x + s * y, -s * x + c * y
        k = np.exp(-0.5 * (u**2 / a**2 + v**2 / b**2))
        kernels.append(k / k.sum())
    kernels = torch.from_numpy(np.stack(kernels))
    basis, coefficients = low_rank_kernels(kernels, 1e-2)
    approx = torch.einsum("nm,mkl->nkl", coefficients, basis)
    assert float(torch.linalg.norm(approx - kernels) / torch.linalg.norm(kernels)) <= 1e-2
    torch.testing.assert_close(
        basis.reshape(len(basis), -1) @ basis.reshape(len(basis), -1).T, torch.eye(len(basis), dtype=torch.float64)
    )


@pytest.mark.parametrize("terms_per_batch", [1, 3])
def test_batched_transforms_equal_the_term_by_term_path(monkeypatch, terms_per_batch):
    """On the CPU outside autograd the terms are transformed in batches (``BATCH_ELEMENTS``); with autograd,
    one by one: both are the same operator, and the batched adjoint passes the dot-product test."""
    import edofproj.imaging.field_varying as module

    rng = np.random.default_rng(5)
    H, W = 30, 44
    cy, cx = np.linspace(0, H - 1, 3), np.linspace(0, W - 1, 4)
    kernels = rng.random((3, 4, 3, 9, 9))
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W))
    monkeypatch.setattr(module, "BATCH_ELEMENTS", terms_per_batch * 2 * 3 * op.grid[0] * op.grid[1])
    assert len(op._chunks(torch.zeros(2, 3, H, W))) == -(-op.rank // terms_per_batch) > 1
    x = torch.from_numpy(rng.standard_normal((2, 3, H, W)))
    y = torch.from_numpy(rng.standard_normal((2, 3, H, W)))
    tracked_x, tracked_y = x.clone().requires_grad_(True), y.clone().requires_grad_(True)
    torch.testing.assert_close(op(x), op(tracked_x).detach(), rtol=0, atol=1e-12)
    torch.testing.assert_close(op.adjoint(y), op.adjoint(tracked_y).detach(), rtol=0, atol=1e-12)
    torch.testing.assert_close(op(x), op(x), rtol=0, atol=0)  # the kept frame buffer's padding stays zero
    left, right = float((op(x) * y).sum()), float((x * op.adjoint(y)).sum())
    assert abs(left - right) <= 1e-10 * abs(left)


@pytest.mark.parametrize("terms_per_batch", [1, 4])
def test_colours_of_unequal_rank_skip_their_padding_and_stay_exact(monkeypatch, terms_per_batch):
    """Red's kernels one Gaussian everywhere (rank 1), green's and blue's random (rank 12): the CPU path
    transforms each colour's own terms only, and equals the dense per-pixel sum, the autograd path and
    the dot-product test."""
    import edofproj.imaging.field_varying as module

    rng = np.random.default_rng(7)
    H, W, K = 23, 31, 7
    cy, cx = np.array([2.0, 11.0, 20.0]), np.array([0.0, 9.5, 18.0, 30.0])
    kernels = rng.random((3, 4, 3, K, K))
    kernels[:, :, 0] = gaussian(1.0, 1.5, K // 2)
    kernels /= kernels.sum(axis=(-1, -2), keepdims=True)
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W))
    assert op.channel_ranks == [1, 12, 12] and op.rank == 12
    monkeypatch.setattr(module, "BATCH_ELEMENTS", terms_per_batch * op.grid[0] * op.grid[1])
    image = rng.random((3, H, W))
    x = torch.from_numpy(image)[None]
    np.testing.assert_allclose(op(x)[0].numpy(), dense_blur(image, kernels, cy, cx), atol=1e-12)
    y = torch.from_numpy(rng.standard_normal((1, 3, H, W)))
    torch.testing.assert_close(op.adjoint(y), op.adjoint(y.clone().requires_grad_(True)).detach(), rtol=0, atol=1e-12)
    left, right = float((op(x) * y).sum()), float((x * op.adjoint(y)).sum())
    assert abs(left - right) <= 1e-10 * abs(left)
