"""Projection with field-dependent PSFs against a brute-force per-pixel sum."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from edofproj.errors import EdofprojError
from edofproj.imaging import project
from edofproj.imaging.field_varying import field_centres_px, hat_weights, project_field_varying
from edofproj.optics.aberrations import FieldAberrations, PupilAberration
from edofproj.optics.field_psfs import field_grid_axes, field_psf_grid
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_bank import PSFSimulator
from edofproj.optics.spectra import Spectrum


def brute_force(image: np.ndarray, grid: np.ndarray, cy, cx, haze: bool = True) -> np.ndarray:
    """out(y) = sum_x' I(x') p(y - x'; x'), p bilinearly interpolated between grid PSFs
    (clamped beyond the outer centres), plus the lost energy as a uniform haze."""
    C, H, W = image.shape
    K = grid.shape[-1]
    m = K // 2
    yy, xx = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    where = np.stack([np.clip(yy, cy[0], cy[-1]), np.clip(xx, cx[0], cx[-1])], axis=-1)
    per_pixel = RegularGridInterpolator((cy, cx), grid, method="linear")(where)  # (H, W, C, K, K)
    out = np.zeros((C, H + 2 * m, W + 2 * m))
    lost = np.zeros(C)
    for y in range(H):
        for x in range(W):
            p = per_pixel[y, x]
            out[:, y : y + K, x : x + K] += image[:, y, x, None, None] * p
            lost += image[:, y, x] * (1 - p.sum(axis=(-1, -2)))
    out = out[:, m : m + H, m : m + W]
    return out + (lost / (H * W))[:, None, None] if haze else out


def test_field_varying_projection_equals_brute_force():
    rng = np.random.default_rng(1)
    H, W, K = 13, 17, 5
    image = rng.uniform(0, 1, (3, H, W))
    grid = rng.uniform(0, 1, (2, 3, 3, K, K))
    grid *= rng.uniform(0.7, 1.0, (2, 3, 3, 1, 1)) / grid.sum(axis=(-1, -2), keepdims=True)
    cy, cx = np.array([2.0, 10.5]), np.array([1.0, 8.0, 15.0])
    got = project_field_varying(torch.from_numpy(image)[None], torch.from_numpy(grid), cy, cx)[0].numpy()
    expected = brute_force(image, grid, cy, cx)
    assert np.allclose(got, expected, atol=1e-12)


def test_a_spatially_constant_field_is_project():
    rng = np.random.default_rng(2)
    image = torch.from_numpy(rng.uniform(-0.1, 1.1, (2, 3, 20, 24)))
    psf = torch.from_numpy(rng.uniform(0, 1, (1, 3, 7, 7)))
    psf = 0.9 * psf / psf.sum(dim=(-1, -2), keepdim=True)
    grid = psf[0].expand(3, 2, 3, 7, 7)
    got = project_field_varying(image, grid, field_centres_px([-0.5, 0, 0.5], 20), field_centres_px([-1, 1], 24))
    assert torch.allclose(got, project(image, psf), atol=1e-12)


def test_hat_weights_partition_unity_and_field_edges():
    w = hat_weights([3.0, 9.0, 20.0], 25)
    assert np.allclose(w.sum(0), 1.0) and w[0, 6] == pytest.approx(0.5)
    assert field_centres_px([-1, 1], 800).tolist() == [-0.5, 799.5]
    with pytest.raises(EdofprojError, match="increasing"):
        hat_weights([3.0, 3.0], 10)


def test_field_psf_grid_puts_each_points_aberration_at_its_node():
    geo = ProjectorGeometry()
    sim = PSFSimulator(geo, Spectrum.monochromatic(550), 9, 256, engine="2d")
    astig = PupilAberration.from_zernike_um({6: 0.2})
    points = np.array([[-1, 0], [1, 0], [-1, 1], [1, 1]], dtype=float)
    field = FieldAberrations(points, (PupilAberration(), astig, PupilAberration(), PupilAberration()))
    xs, ys, index = field_grid_axes(field)
    assert xs.tolist() == [-1, 1] and ys.tolist() == [0, 1]
    grid = field_psf_grid(sim, None, [0.5], field)
    assert grid.shape == (2, 2, 1, 1, 9, 9)
    assert torch.allclose(grid[0, 0], grid[1, 1]) and not torch.allclose(grid[0, 1], grid[0, 0], atol=1e-4)
    sim.engine.aberration = astig
    assert torch.allclose(grid[0, 1], sim(None, [0.5]))
    with pytest.raises(EdofprojError, match="full grid"):
        field_grid_axes(FieldAberrations(points[:3], field.pupils[:3]))


def test_per_patch_table_draws_field_points_and_interpolates_in_inverse_depth(tmp_path):
    from edofproj.training.finetune import MeasuredPSFTable

    rng = np.random.default_rng(3)
    files, psfs = [], []
    for depth in (0.4, 0.8):
        psf = rng.uniform(0, 1, (2, 3, 5, 5)).astype(np.float32)  # two patches
        psf *= 0.9 / psf.sum(axis=(-1, -2), keepdims=True)  # physical: 0.9 of the light in the window
        np.savez(tmp_path / f"p{depth}.npz", psf=psf, depths_m=np.array([depth]))
        files.append(tmp_path / f"p{depth}.npz")
        psfs.append(psf)
    table = MeasuredPSFTable.from_patch_files(files, seed=0)
    z = 1 / (0.5 / 0.4 + 0.5 / 0.8)  # halfway in 1/z
    out = table(np.full(64, z)).numpy()
    halves = [0.5 * (psfs[0][p] + psfs[1][p]) for p in (0, 1)]
    which = [int(np.argmin([np.abs(o - h).max() for h in halves])) for o in out]
    assert all(np.allclose(o, halves[w], atol=1e-6) for o, w in zip(out, which))
    assert 10 < sum(which) < 54  # both field points are drawn
    np.savez(tmp_path / "bad.npz", psf=np.full((3, 3, 5, 5), 0.03, np.float32), depths_m=np.array([0.6]))
    with pytest.raises(EdofprojError, match="differ in patches"):
        MeasuredPSFTable.from_patch_files(files + [tmp_path / "bad.npz"])
