"""Projection with haze: exact energy bookkeeping, identity for an impulse PSF, clamping."""

import numpy as np
import pytest
import scipy.signal
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.projection import haze_term, project


def lossy_psf(k=9, kept=0.8, channels=3, seed=0):
    """A random PSF whose window keeps ``kept`` of the energy (different per channel)."""
    psf = torch.rand(1, channels, k, k, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    keep = torch.linspace(kept - 0.1, kept + 0.1, channels, dtype=torch.float64)
    return psf / psf.sum(dim=(-1, -2), keepdim=True) * keep[None, :, None, None]


def test_total_light_is_conserved_on_a_canvas_with_a_black_margin():
    psf = lossy_psf(k=9)
    content = torch.rand(2, 3, 20, 25, dtype=torch.float64)
    canvas = torch.nn.functional.pad(content, (4, 4, 4, 4))  # margin K//2: nothing leaves the canvas
    out = project(canvas, psf)
    np.testing.assert_allclose(out.sum(dim=(-1, -2)).numpy(), content.sum(dim=(-1, -2)).numpy(), rtol=1e-12)


def test_uniform_image_stays_uniform_away_from_the_border():
    psf = lossy_psf(k=7, kept=0.6)
    level = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)[None, :, None, None]
    out = project(level.expand(1, 3, 30, 30).clone(), psf)
    interior = out[..., 3:-3, 3:-3]
    np.testing.assert_allclose(interior.numpy(), level.expand_as(interior).numpy(), atol=1e-12)
    # at the border the window reaches outside the image, which is dark: less light there
    assert torch.all(out[..., 0, 0] < level[..., 0, 0])


def test_impulse_psf_is_the_identity_and_has_no_haze():
    psf = torch.zeros(1, 3, 5, 5)
    psf[..., 2, 2] = 1.0
    image = torch.rand(2, 3, 17, 19)
    np.testing.assert_allclose(project(image, psf).numpy(), image.numpy(), atol=1e-6)


def test_image_is_clamped_to_what_a_projector_can_emit():
    psf = lossy_psf(k=5, kept=0.7)
    image = torch.randn(1, 3, 16, 16, dtype=torch.float64) * 2
    np.testing.assert_allclose(project(image, psf).numpy(), project(image.clamp(0, 1), psf).numpy())


def test_equals_independent_scipy_blur_plus_haze():
    psf = lossy_psf(k=9)
    image = torch.rand(1, 3, 24, 31, dtype=torch.float64)
    out = project(image, psf).numpy()
    for c in range(3):
        blurred = scipy.signal.fftconvolve(image[0, c].numpy(), psf[0, c].numpy(), mode="same")
        expected = blurred + (1 - psf[0, c].sum().item()) * image[0, c].mean().item()
        np.testing.assert_allclose(out[0, c], expected, atol=1e-12)
    no_haze = project(image, psf, haze=False).numpy()
    np.testing.assert_allclose(out - no_haze, haze_term(image, psf).expand_as(image).numpy(), atol=1e-12)


def test_per_sample_psfs():
    psfs = torch.cat([lossy_psf(k=5, seed=1), lossy_psf(k=5, seed=2)])
    image = torch.rand(2, 3, 12, 12, dtype=torch.float64)
    out = project(image, psfs)
    for b in range(2):
        np.testing.assert_allclose(out[b].numpy(), project(image[b : b + 1], psfs[b : b + 1])[0].numpy())


def test_gradient_reaches_image_and_psf():
    image = torch.rand(1, 3, 10, 10, requires_grad=True)
    psf = lossy_psf(k=3).float().requires_grad_(True)
    project(image, psf).square().sum().backward()
    assert image.grad.abs().sum() > 0 and psf.grad.abs().sum() > 0


@pytest.mark.parametrize(
    "image_shape, psf_shape, message",
    [
        ((3, 8, 8), (1, 3, 3, 3), "must be \\(B, C, H, W\\)"),
        ((2, 3, 8, 8), (3, 3, 3, 3), "does not fit"),
        ((1, 3, 8, 8), (1, 3, 3, 5), "K, K"),
    ],
)
def test_bad_shapes_raise_one_line_errors(image_shape, psf_shape, message):
    with pytest.raises(EdofprojError, match=message):
        project(torch.rand(image_shape), torch.rand(psf_shape))
