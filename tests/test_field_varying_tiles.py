"""The tiled low-rank form of the field-varying blur (imaging.field_varying.FieldVaryingBlur, ``tiles=``):
the same operator as the single whole-image basis and as a dense per-pixel sum, its adjoint, the
per-tile truncation bound, a lit pixel's spread, and the automatic choice of the tiling."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.field_varying import FieldVaryingBlur


def interp_weights(position: float, centres) -> np.ndarray:
    """Tent weights of one pixel on the nodes ``centres``, by hand: linear between the two bracketing
    nodes, all on the outermost node beyond the ends."""
    c = np.asarray(centres, dtype=float)
    w = np.zeros(len(c))
    if position <= c[0]:
        w[0] = 1.0
    elif position >= c[-1]:
        w[-1] = 1.0
    else:
        j = int(np.searchsorted(c, position, side="right")) - 1
        t = (position - c[j]) / (c[j + 1] - c[j])
        w[j], w[j + 1] = 1.0 - t, t
    return w


def dense_operator(kernels: np.ndarray, cy, cx, hw: tuple[int, int], channel: int = 0) -> np.ndarray:
    """``(H W, H W)`` matrix of the blur of one channel: column ``x'`` is pixel ``x'``'s bilinearly
    interpolated kernel placed at ``x'`` and cropped to the image (a per-pixel loop, no FFT, no basis)."""
    H, W = hw
    K = kernels.shape[-1]
    r = K // 2
    c = min(channel, kernels.shape[2] - 1)
    matrix = np.zeros((H * W, H, W))
    for y in range(H):
        wy = interp_weights(y, cy)
        for x in range(W):
            psf = np.einsum("i,j,ijkl->kl", wy, interp_weights(x, cx), kernels[:, :, c])
            frame = np.zeros((H + 2 * r, W + 2 * r))
            frame[y : y + K, x : x + K] = psf
            matrix[y * W + x] = frame[r : r + H, r : r + W]
    return matrix.reshape(H * W, H * W).T


def random_setup(channels: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    H, W, K = 29, 37, 7
    cy, cx = np.array([1.0, 9.0, 17.5, 27.0]), np.array([0.0, 8.0, 15.0, 24.5, 36.0])
    kernels = rng.random((4, 5, channels, K, K))
    return rng, (H, W), cy, cx, kernels


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("tiles", [(2, 3), (3, 2), (4, 5), (7, 6)])
def test_tiled_operator_equals_the_whole_image_one_and_the_dense_sum(channels, tiles):
    # uneven bands (29 and 37 px do not divide evenly); (7, 6): tiles of 4-5 px, smaller than the 7 px kernels
    rng, hw, cy, cx, kernels = random_setup(channels)
    whole = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, hw, tiles=(1, 1))
    tiled = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, hw, tiles=tiles)
    assert tiled.tiles == tiles and len(tiled.source_tiles) == tiles[0] * tiles[1]
    assert tiled.rank < whole.rank == 20  # fewer nodes per tile: fewer basis kernels
    x = torch.from_numpy(rng.random((2, 3, *hw)))
    y = torch.from_numpy(rng.random((2, 3, *hw)))
    dense = np.stack([dense_operator(kernels, cy, cx, hw, c) for c in range(3)])  # (3, HW, HW)
    expected_ax = np.einsum("cpq,bcq->bcp", dense, x.reshape(2, 3, -1).numpy()).reshape(2, 3, *hw)
    expected_aty = np.einsum("cqp,bcq->bcp", dense, y.reshape(2, 3, -1).numpy()).reshape(2, 3, *hw)
    with torch.no_grad():  # the batched SciPy path
        np.testing.assert_allclose(tiled(x).numpy(), whole(x).numpy(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(tiled.adjoint(y).numpy(), whole.adjoint(y).numpy(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(tiled(x).numpy(), expected_ax, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tiled.adjoint(y).numpy(), expected_aty, rtol=0, atol=1e-12)
    tracked_x, tracked_y = x.clone().requires_grad_(True), y.clone().requires_grad_(True)  # the torch.fft path
    ax, aty = tiled(tracked_x), tiled.adjoint(tracked_y)
    np.testing.assert_allclose(ax.detach().numpy(), expected_ax, rtol=0, atol=1e-12)
    np.testing.assert_allclose(aty.detach().numpy(), expected_aty, rtol=0, atol=1e-12)
    # autograd through the tiles: the gradient of <A x, y> in x is A^T y
    (gradient,) = torch.autograd.grad((ax * y).sum(), tracked_x)
    np.testing.assert_allclose(gradient.numpy(), expected_aty, rtol=0, atol=1e-12)


@pytest.mark.parametrize("tolerance", [0.0, 1e-2])
@pytest.mark.parametrize("grad", [False, True])
def test_tiled_adjoint_passes_the_dot_product_test(tolerance, grad):
    rng, hw, cy, cx, kernels = random_setup(3, seed=1)
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, hw, rank_tolerance=tolerance, tiles=(3, 4))
    x = torch.from_numpy(rng.standard_normal((2, 3, *hw))).requires_grad_(grad)
    y = torch.from_numpy(rng.standard_normal((2, 3, *hw))).requires_grad_(grad)
    left, right = float((op(x) * y).sum().detach()), float((x * op.adjoint(y)).sum().detach())
    assert abs(left - right) <= 1e-12 * abs(left)


def gaussian(sigma_u: float, sigma_v: float, angle: float, radius: int) -> np.ndarray:
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    u, v = np.cos(angle) * xx + np.sin(angle) * yy, -np.sin(angle) * xx + np.cos(angle) * yy
    k = np.exp(-0.5 * (u**2 / sigma_u**2 + v**2 / sigma_v**2))
    return k / k.sum()


def rotating_field(gy: int, gx: int, radius: int) -> np.ndarray:
    """``(gy, gx, 1, K, K)`` anisotropic Gaussians whose long axis turns by 180 degrees from left to right,
    their widths growing from top to bottom."""
    return np.stack(
        [[[gaussian(1.0 + 2.5 * i / gy + 1.5, 0.8, np.pi * j / gx, radius)] for j in range(gx)] for i in range(gy)]
    )


def test_per_tile_truncation_stays_within_its_tolerance_bound():
    """Pixel ``x'`` of tile ``t`` spreads as ``sum_g w_g(x') h~_tg`` with ``h~_tg`` the tile's truncated kernels;
    the weights are convex, so its error is at most ``max_g ||h_g - h~_tg|| <= tau ||H_t||_F`` (``H_t`` the
    tile's node kernels together, the tolerance's definition)."""
    H, W, tau = 30, 40, 0.05
    cy, cx = np.linspace(0, H - 1, 5), np.linspace(0, W - 1, 7)
    kernels = rotating_field(5, 7, 4)
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W), rank_tolerance=tau, tiles=(2, 3))
    exact = dense_operator(kernels, cy, cx, (H, W))
    with torch.no_grad():
        columns = op(torch.eye(H * W, dtype=torch.float64).reshape(H * W, 1, H, W)).reshape(H * W, H * W).T
    error = np.linalg.norm(columns.numpy() - exact, axis=0).reshape(H, W)  # per source pixel
    assert error.max() > 1e-6  # the truncation does drop something
    rows_bands, cols_bands = [(0, 15), (15, 30)], [(0, 13), (13, 27), (27, 40)]
    for y0, y1 in rows_bands:
        for x0, x1 in cols_bands:
            node_rows = sorted({int(i) for y in range(y0, y1) for i in np.nonzero(interp_weights(y, cy))[0]})
            node_cols = sorted({int(j) for x in range(x0, x1) for j in np.nonzero(interp_weights(x, cx))[0]})
            bound = tau * np.linalg.norm(kernels[node_rows][:, node_cols])
            assert error[y0:y1, x0:x1].max() <= bound


def test_a_lit_pixel_spreads_as_its_interpolated_kernel():
    rng = np.random.default_rng(3)
    H, W, K = 48, 60, 9
    cy, cx = np.array([3.0, 20.0, 41.0]), np.array([0.0, 25.0, 39.0, 59.0])
    kernels = rng.random((3, 4, 1, K, K))
    op = FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (H, W), tiles=(2, 2))  # tiles 24 x 30 px
    y, x = 11, 32  # inside tile (0, 1), 7 px from its nearest border: its light (radius 4) stays in the tile
    ty, tx = (y - cy[0]) / (cy[1] - cy[0]), (x - cx[1]) / (cx[2] - cx[1])
    psf = (
        (1 - ty) * (1 - tx) * kernels[0, 1, 0]
        + (1 - ty) * tx * kernels[0, 2, 0]
        + ty * (1 - tx) * kernels[1, 1, 0]
        + ty * tx * kernels[1, 2, 0]
    )
    image = torch.zeros(1, 1, H, W, dtype=torch.float64)
    image[0, 0, y, x] = 1.0
    with torch.no_grad():
        out = op(image)[0, 0].numpy()
    expected = np.zeros((H, W))
    expected[y - 4 : y + 5, x - 4 : x + 5] = psf
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-13)


def test_the_automatic_tiling_splits_a_rotating_field_and_not_a_constant_one():
    H, W, radius = 200, 280, 7
    cy, cx = np.linspace(0, H - 1, 6), np.linspace(0, W - 1, 9)
    constant = np.broadcast_to(gaussian(2.0, 1.0, 0.3, radius), (6, 9, 1, 15, 15)).copy()
    flat = FieldVaryingBlur(torch.from_numpy(constant), cy, cx, (H, W), rank_tolerance=1e-2)
    assert flat.tiles == (1, 1) and flat.rank == 1
    turning = FieldVaryingBlur(torch.from_numpy(rotating_field(6, 9, radius)), cy, cx, (H, W), rank_tolerance=1e-2)
    whole = FieldVaryingBlur(torch.from_numpy(rotating_field(6, 9, radius)), cy, cx, (H, W), 1e-2, tiles=(1, 1))
    assert turning.tiles[0] * turning.tiles[1] > 1
    assert turning.rank < whole.rank  # each tile's kernels span fewer directions
    assert turning.convolutions == int(turning.tile_ranks.sum())


def test_a_bad_tiling_is_refused_in_one_line():
    k = torch.ones(2, 2, 1, 3, 3) / 9
    for tiles in [(0, 1), (1, 11), (2,)]:
        with pytest.raises(EdofprojError, match="tiles must be"):
            FieldVaryingBlur(k, [0, 9], [0, 9], (10, 10), tiles=tiles)
