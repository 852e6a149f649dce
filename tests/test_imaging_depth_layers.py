"""Depth-layer rendering: reduces to flat projection, blends linearly in 1/z, conserves light."""

import numpy as np
import pytest
import scipy.signal
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.depth_layers import bank_layers, layer_depths_m, layer_weights, render_depth_map
from edofproj.imaging.projection import project
from edofproj.optics.psf_bank import PSFBank


def gaussian_psfs(depths_m, k=11, focus_m=0.5, kept=0.9):
    """Synthetic PSFs: Gaussians whose width grows with |1/z - 1/v| and that keep ``kept`` of the energy."""
    y, x = np.mgrid[-(k // 2) : k // 2 + 1, -(k // 2) : k // 2 + 1]
    psfs = []
    for z in np.atleast_1d(depths_m):
        sigma = 0.4 + 2.0 * abs(1 / z - 1 / focus_m)
        g = np.exp(-(x**2 + y**2) / (2 * sigma**2))
        psfs.append(np.stack([g / g.sum() * (kept - 0.05 * c) for c in range(3)]))
    return torch.from_numpy(np.array(psfs))


def test_constant_depth_map_equals_the_flat_projection():
    image = torch.rand(2, 3, 24, 30)
    depth = np.full((24, 30), 0.42)
    out = render_depth_map(image, depth, gaussian_psfs, layers=8)
    flat = project(image, gaussian_psfs([0.42]).float())
    assert (out - flat).abs().max() < 1e-5


def test_constant_map_on_an_interior_layer_uses_only_that_layer():
    image = torch.rand(1, 3, 20, 20, dtype=torch.float64)
    layers = np.array([0.3, 0.45, 0.8])
    out = render_depth_map(image, np.full((20, 20), 0.45), gaussian_psfs(layers), layers=layers)
    flat = project(image, gaussian_psfs([0.45]))
    assert (out - flat).abs().max() < 1e-12


def test_two_regions_equal_independent_masked_convolutions():
    rng = np.random.default_rng(0)
    image = rng.random((3, 18, 26))
    depth = np.where(np.arange(26)[None, :] < 11, 0.3, 0.8) * np.ones((18, 1))
    psfs = gaussian_psfs([0.3, 0.8]).numpy()
    out = render_depth_map(torch.from_numpy(image)[None], depth, torch.from_numpy(psfs), layers=[0.3, 0.8])[0].numpy()
    for c in range(3):
        expected = 0.0
        for layer, z in enumerate((0.3, 0.8)):
            masked = image[c] * (depth == z)
            expected = expected + scipy.signal.fftconvolve(masked, psfs[layer, c], mode="same")
            expected = expected + (1 - psfs[layer, c].sum()) * masked.mean()
        np.testing.assert_allclose(out[c], expected, atol=1e-12)


def test_weights_are_hat_functions_of_inverse_depth():
    layers = np.array([0.3, 0.4, 0.6])
    z = np.array([[0.3, 0.4, 0.6, 1 / (0.5 / 0.3 + 0.5 / 0.4), 1 / (0.25 / 0.4 + 0.75 / 0.6)]])
    w = layer_weights(z, layers).numpy()[:, 0, :]  # (n, 5)
    expected = np.array([[1, 0, 0, 0.5, 0], [0, 1, 0, 0.5, 0.25], [0, 0, 1, 0, 0.75]])
    np.testing.assert_allclose(w, expected, atol=1e-12)
    random_z = np.random.default_rng(1).uniform(0.3, 0.6, (7, 9))
    np.testing.assert_allclose(layer_weights(random_z, layers).sum(0).numpy(), 1.0, atol=1e-12)


def test_blending_interpolates_the_psf_energy_linearly_in_inverse_depth():
    # impulse PSFs that keep e_l of the light, no haze: a pixel shows I * sum_l w_l e_l
    layers = np.array([0.3, 0.5, 0.8])
    energy = np.array([0.9, 0.6, 0.3])
    psfs = torch.zeros(3, 3, 3, 3, dtype=torch.float64)
    psfs[:, :, 1, 1] = torch.from_numpy(energy)[:, None]
    z = np.linspace(0.3, 0.8, 40)[None, :] * np.ones((5, 1))
    image = torch.rand(1, 3, 5, 40, dtype=torch.float64)
    out = render_depth_map(image, z, psfs, layers=layers, haze=False)
    expected_energy = np.interp(-1 / z, -1 / layers, energy)
    np.testing.assert_allclose(out[0].numpy(), image[0].numpy() * expected_energy, atol=1e-12)


def test_light_is_conserved_for_a_varying_depth_map():
    image = torch.nn.functional.pad(torch.rand(1, 3, 20, 30, dtype=torch.float64), (5, 5, 5, 5))
    z = np.random.default_rng(2).uniform(0.3, 0.8, image.shape[-2:])
    out = render_depth_map(image, z, gaussian_psfs, layers=6)
    np.testing.assert_allclose(out.sum(dim=(-1, -2)).numpy(), image.sum(dim=(-1, -2)).numpy(), rtol=1e-10)


def test_default_layers_are_evenly_spaced_in_inverse_depth():
    depths = layer_depths_m(0.3, 0.8, 8)
    assert depths[0] == 0.3 and depths[-1] == 0.8 and len(depths) == 8
    np.testing.assert_allclose(np.diff(1 / depths), np.full(7, (1 / 0.8 - 1 / 0.3) / 7))
    assert layer_depths_m(0.5, 0.5, 8).tolist() == [0.5]


def test_per_sample_depth_maps():
    image = torch.rand(2, 3, 12, 12, dtype=torch.float64)
    maps = np.stack([np.full((12, 12), 0.3), np.full((12, 12), 0.8)])
    out = render_depth_map(image, maps, gaussian_psfs, layers=[0.3, 0.8])
    np.testing.assert_allclose(out[0].numpy(), project(image[:1], gaussian_psfs([0.3]))[0].numpy(), atol=1e-12)
    np.testing.assert_allclose(out[1].numpy(), project(image[1:], gaussian_psfs([0.8]))[0].numpy(), atol=1e-12)


def test_bank_layers_bracket_the_map():
    bank = PSFBank(
        psf=gaussian_psfs([0.3, 0.4, 0.5, 0.6, 0.8]).float(),
        depths_m=np.array([0.3, 0.4, 0.5, 0.6, 0.8]),
        pixel_pitch_m=np.ones(5),
    )
    depths, psf = bank_layers(bank, np.array([[0.45, 0.55]]))
    assert depths.tolist() == [0.4, 0.5, 0.6]
    assert torch.equal(psf, bank.psf[1:4])
    depths, _ = bank_layers(bank, np.array([[0.5, 0.5]]))
    assert depths.tolist() == [0.5]
    with pytest.raises(EdofprojError, match="spans 250.0-500.0 mm but the PSFs cover 300.0-800.0 mm"):
        bank_layers(bank, np.array([[0.25, 0.5]]))


@pytest.mark.parametrize(
    "depth, message",
    [
        (np.full((5, 6), 0.5), "shape \\(5, 6\\) but the image is \\(8, 8\\)"),
        (np.full((8, 8), -1.0), "positive and finite"),
        (np.full((8, 8), np.nan), "positive and finite"),
    ],
)
def test_bad_depth_maps_raise(depth, message):
    with pytest.raises(EdofprojError, match=message):
        render_depth_map(torch.rand(1, 3, 8, 8), depth, gaussian_psfs)


def test_too_few_psfs_raise():
    with pytest.raises(EdofprojError, match="expected 3 PSFs"):
        render_depth_map(
            torch.rand(1, 3, 8, 8), np.full((8, 8), 0.5), gaussian_psfs([0.3, 0.5]), layers=[0.3, 0.5, 0.8]
        )
