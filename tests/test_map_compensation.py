"""Compensation from a measured PSF map: the blur a synthetic map defines (dot spreads against the
map's covariances), per-colour maps, the field-varying Wiener filter against the invariant one,
and box-constrained least squares on a target inside the achievable set."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.field_varying import FieldVaryingWiener, field_varying_cls
from edofproj.compensation.wiener import wiener_deconvolve
from edofproj.errors import EdofprojError
from edofproj.imaging.field_varying import FieldVaryingBlur, hat_weights
from edofproj.procams.map_compensation import compensate_with_map
from edofproj.procams.measured_blur import measured_blur
from edofproj.procams.psf_map import PSFMap, covariance

H, W = 49, 65  # nodes every 8 px fall on whole pixels: 0, 8, ..., 48 and 0, ..., 64


def synthetic_map(sigma_scale: float = 1.0, channel: str = "mean", constant: bool = False, step: float = 8.0) -> PSFMap:
    """A tilted-screen-like map on dots every ``step`` px: widths grow along x, the ellipse turns along y."""
    xs, ys = np.arange(0.0, W, step), np.arange(0.0, H, step)
    cov = np.empty((len(ys), len(xs), 2, 2))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            t = 0.0 if constant else x / (W - 1)
            cov[i, j] = covariance(
                sigma_scale * (0.6 + 0.9 * t), sigma_scale * (0.9 + 0.8 * t), 0.0 if constant else 0.5 * y / H
            )
    return PSFMap(xs=xs, ys=ys, cov=cov, offset_px=np.zeros(2), fitted=np.ones(cov.shape[:2], bool),
                  projector_hw=(H, W), channel=channel)  # fmt: skip


def test_a_dot_spreads_with_the_maps_covariance_where_it_is():
    psf_map = synthetic_map()
    op = measured_blur(psf_map, node_spacing_px=8, rank_tolerance=0.0)
    for y, x in [(8, 8), (24, 32), (40, 56), (16, 48)]:  # on nodes: the PSF there is the node's own Gaussian
        dot = torch.zeros(1, 1, H, W, dtype=torch.float64)
        dot[..., y, x] = 1.0
        spread = op(dot)[0, 0].numpy()
        yy, xx = np.mgrid[0:H, 0:W]
        assert spread.sum() == pytest.approx(1.0, abs=1e-9)
        dy, dx = yy - y, xx - x
        moments = np.array([[np.sum(spread * dx * dx), np.sum(spread * dx * dy)],
                            [np.sum(spread * dx * dy), np.sum(spread * dy * dy)]])  # fmt: skip
        # the sampled Gaussian cut at 4 sigma: its second moments within 1 % of the covariance
        np.testing.assert_allclose(moments, psf_map.covariance_at(np.array(x), np.array(y)), rtol=0.01, atol=0.01)


def test_each_colour_blurs_with_its_own_map():
    maps = {"red": synthetic_map(1.0, "red"), "green": synthetic_map(1.5, "green"), "blue": synthetic_map(2.0, "blue")}
    op = measured_blur(maps, node_spacing_px=8, rank_tolerance=0.0)
    assert op.channels == 3
    image = torch.rand(1, 3, H, W, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    blurred = op(image)
    for c, name in enumerate(("red", "green", "blue")):
        alone = measured_blur(maps[name], node_spacing_px=8, rank_tolerance=0.0)
        assert alone.channels == 1
        np.testing.assert_allclose(blurred[:, c], alone(image[:, c : c + 1])[:, 0], atol=1e-12)
    # a file with only the white map blurs every plane with it
    assert measured_blur({"mean": synthetic_map()}, node_spacing_px=8).channels == 1


def test_wiener_with_a_constant_map_is_the_invariant_wiener():
    op = measured_blur(synthetic_map(1.3, constant=True), node_spacing_px=8, rank_tolerance=0.0)
    kernel = op.kernels[0, 0]  # (1, K, K): every node's
    target = torch.rand(1, 3, H, W, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    for nsr in (1e-3, 1e-2):
        invariant = wiener_deconvolve(target, kernel, nsr)
        # its kernels on the whole filtering frame: the invariant filter itself
        whole = FieldVaryingWiener(op, nsr)
        exact = FieldVaryingWiener(op, nsr, frame_px=whole.frame)
        assert float((exact(target) - invariant).abs().max()) < 1e-12
        # on the default smaller periodic frame: equal up to the Wiener kernel's tail, well within an 8-bit step
        assert float((whole(target) - invariant).abs().max()) < 1e-3


def test_field_varying_wiener_blends_the_nodes_wiener_estimates():
    # independent: every node's kernel through the invariant Wiener, blended by the tent weights
    op = measured_blur(synthetic_map(), node_spacing_px=16, rank_tolerance=0.0)
    nsr = 3e-3
    target = torch.rand(1, 3, H, W, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    wy, wx = hat_weights(op.centres_y_px, H), hat_weights(op.centres_x_px, W)
    expected = np.zeros((3, H, W))
    for i in range(len(op.centres_y_px)):
        for j in range(len(op.centres_x_px)):
            # unclamped invariant Wiener: shift the target so that the clamp does not bite
            node = wiener_deconvolve(target * 0.05 + 0.5, op.kernels[i, j], nsr)[0].numpy()
            expected += np.outer(wy[i], wx[j]) * (node - 0.5) / 0.05
    wiener = FieldVaryingWiener(op, nsr, node_spacing_px=0, rank_tolerance=0.0)
    exact = FieldVaryingWiener(op, nsr, node_spacing_px=0, rank_tolerance=0.0, frame_px=wiener.frame)
    got = exact(target * 0.05 + 0.5)[0].numpy()
    np.testing.assert_allclose((got - 0.5) / 0.05, expected, atol=1e-10)


def test_cls_recovers_an_achievable_target_to_40_db():
    op = measured_blur(synthetic_map(), node_spacing_px=8, rank_tolerance=0.0)
    generator = torch.Generator().manual_seed(3)
    truth = torch.nn.functional.avg_pool2d(
        torch.rand(1, 3, H + 2, W + 2, dtype=torch.float64, generator=generator), 3, 1
    )
    target = op(truth)  # inside the achievable set: some x in [0, 1] shows it exactly
    result = compensate_with_map(target, op, "cls", nsr=1e-3, iterations=150)
    assert float(result.image.min()) >= 0.0 and float(result.image.max()) <= 1.0
    mse = float(((op(result.image) - target) ** 2).mean())
    assert 10 * np.log10(1.0 / mse) >= 40.0
    # monotone: the objective never rises, and the start is the Wiener estimate's
    f = result.objective[:, 0]
    assert bool((f[1:] <= f[:-1] + 1e-15).all())
    wiener = compensate_with_map(target, op, "wiener", nsr=1e-3)
    assert float(f[0]) == pytest.approx(0.5 * float(((op(wiener.image) - target) ** 2).sum()), rel=1e-12)


def test_cls_does_better_than_wiener_where_the_box_bites():
    op = measured_blur(synthetic_map(1.5), node_spacing_px=8, rank_tolerance=0.0)
    target = torch.zeros(1, 1, H, W, dtype=torch.float64)
    target[..., 12:36, 16:48] = 1.0  # a white block: its sharp edges need light beyond [0, 1]
    wiener = compensate_with_map(target, op, "wiener", nsr=1e-3)
    cls = compensate_with_map(target, op, "cls", nsr=1e-3, iterations=60)
    assert float(((op(cls.image) - target) ** 2).sum()) < float(((op(wiener.image) - target) ** 2).sum())


def test_bad_requests_are_refused_in_one_line():
    op = measured_blur(synthetic_map(), node_spacing_px=8)
    with pytest.raises(EdofprojError, match="height x width"):
        compensate_with_map(torch.zeros(1, 3, H, W + 1), op, "cls", nsr=1e-3)
    with pytest.raises(EdofprojError, match="unknown method"):
        compensate_with_map(torch.zeros(1, 3, H, W), op, "net", nsr=1e-3)
    with pytest.raises(EdofprojError, match="NSR"):
        compensate_with_map(torch.zeros(1, 3, H, W), op, "wiener", nsr=-1.0)
    assert isinstance(op, FieldVaryingBlur)
    with pytest.raises(EdofprojError):
        field_varying_cls(torch.zeros(3, H, W), op)


def test_an_edge_fit_at_the_largest_width_does_not_set_the_window():
    psf_map = synthetic_map(step=2.0)  # 25 x 33 dots
    psf_map.cov[0, 0] = covariance(20.0, 20.0, 0.0)  # one dot at the edge ran to MAX_SIGMA_PX
    op = measured_blur(psf_map, node_spacing_px=8)
    widths = np.sqrt(np.linalg.eigvalsh(psf_map.cov)[..., -1]).ravel()
    assert op.kernels.shape[-1] == 2 * int(np.ceil(4 * np.quantile(widths, 0.99))) + 1 < 2 * 80 + 1
    assert np.quantile(widths, 0.99) <= np.sort(widths)[-2]  # the outlier's width is not the window's
    np.testing.assert_allclose(op.kernels.sum(dim=(-1, -2)).numpy(), 1.0, atol=1e-12)  # the cut kernel renormalized
