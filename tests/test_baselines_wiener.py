"""Wiener deconvolution: exact inversion of a blur without spectral zeros, haze, NumPy == PyTorch."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from edofproj.compensation.wiener import (
    TorchWienerCompensator,
    WienerCompensator,
    depth_ensemble_wiener_kernel,
    psnr,
    tune_wiener_nsr,
    wiener_deconvolve,
)
from edofproj.errors import EdofprojError
from edofproj.imaging.convolution import optical_transfer_function
from edofproj.imaging.projection import project


def cross_psf(energy: float = 0.9) -> np.ndarray:
    """5×5 PSF: centre 0.5, four neighbours 0.1 each, scaled to ``energy`` (the rest is haze).

    Its spectrum ``energy·(0.5 + 0.2 cos u + 0.2 cos v)`` never drops below ``0.1·energy``.
    """
    psf = np.zeros((5, 5))
    psf[2, 2] = 0.5
    psf[1, 2] = psf[3, 2] = psf[2, 1] = psf[2, 3] = 0.1
    return np.repeat((energy * psf / psf.sum())[None], 3, axis=0)


def independent_otf(psf: np.ndarray, height: int, width: int, haze: bool = True) -> np.ndarray:
    """rfft2 of the PSF with its centre moved to pixel (0, 0), by NumPy alone; DC set to 1 with haze."""
    k = psf.shape[-1]
    kernel = np.zeros((psf.shape[0], height, width))
    kernel[:, :k, :k] = psf
    otf = np.fft.rfft2(np.roll(kernel, (-(k // 2), -(k // 2)), axis=(-2, -1)))
    if haze:
        otf[:, 0, 0] = 1.0
    return otf


def circular_projection(x: np.ndarray, psf: np.ndarray) -> np.ndarray:
    """Periodic blur (scipy.ndimage, independent of the code under test) plus the haze term."""
    haze = 1.0 - psf.sum(axis=(-1, -2))
    blurred = np.stack([ndimage.convolve(x[c], psf[c], mode="wrap") for c in range(x.shape[0])])
    return blurred + haze[:, None, None] * x.mean(axis=(-1, -2), keepdims=True)


@pytest.fixture
def image():
    return np.random.default_rng(0).uniform(0.05, 0.95, size=(3, 40, 56))


def test_psf_spectrum_has_no_zeros():
    otf = independent_otf(cross_psf(), 40, 56, haze=False)
    np.testing.assert_allclose(
        optical_transfer_function(torch.from_numpy(cross_psf()), (40, 56)).numpy(), otf, atol=1e-12
    )
    assert np.abs(otf).min() > 0.09


def test_inverts_circular_blur_with_haze(image):
    psf = cross_psf()
    observed = circular_projection(image, psf)
    restored = WienerCompensator(psf, nsr=1e-9, pad=False)(observed)
    assert restored.dtype == np.float32 and restored.shape == image.shape
    assert np.abs(restored - image).max() < 1e-5
    restored_torch = wiener_deconvolve(torch.tensor(observed[None]), torch.tensor(psf), 1e-9, pad=False)
    assert np.abs(restored_torch[0].numpy() - image).max() < 1e-7


def test_ignoring_the_haze_misses_the_mean(image):
    psf = cross_psf(energy=0.8)
    observed = circular_projection(image, psf)
    restored = WienerCompensator(psf, nsr=1e-9, haze=False, pad=False)(observed)
    # Without the haze the DC gain is Σp = 0.8 instead of 1: the mean comes out too bright.
    assert restored.mean() - image.mean() > 0.05


def test_reflect_padding_inverts_linear_projection_away_from_the_border(image):
    psf = cross_psf()
    observed = project(torch.tensor(image[None]), torch.tensor(psf[None]))[0].numpy()
    restored = WienerCompensator(psf, nsr=1e-9)(observed)
    border = 8
    inner = (slice(None), slice(border, -border), slice(border, -border))
    assert np.abs(restored[inner] - image[inner]).max() < 2e-3


@pytest.mark.parametrize("nsr", [1e-4, 1e-2])
def test_numpy_and_torch_agree(nsr):
    rng = np.random.default_rng(1)
    psf = rng.uniform(size=(3, 9, 9))
    psf *= 0.9 / psf.sum(axis=(-1, -2), keepdims=True)
    batch = rng.uniform(size=(2, 3, 33, 47)).astype(np.float32)
    numpy_out = WienerCompensator(psf, nsr)(batch)
    torch_out = wiener_deconvolve(torch.tensor(batch), torch.tensor(psf, dtype=torch.float32), nsr).numpy()
    cached = TorchWienerCompensator(psf, nsr)
    cached_out = cached(torch.tensor(batch)).numpy()
    # float32 rounding is amplified by at most max|G| = 1 / (2 sqrt(NSR)).
    tolerance = 1e-6 / np.sqrt(nsr)
    assert np.abs(numpy_out - torch_out).max() < tolerance
    assert np.array_equal(cached_out, cached(torch.tensor(batch)).numpy())
    assert np.abs(cached_out - torch_out).max() < tolerance
    assert np.array_equal(WienerCompensator(psf, nsr)(batch[0]), numpy_out[0])
    assert numpy_out.min() >= 0.0 and numpy_out.max() <= 1.0


def test_per_sample_psfs_match_one_by_one():
    rng = np.random.default_rng(2)
    psfs = torch.tensor(rng.uniform(size=(2, 3, 7, 7)), dtype=torch.float32)
    psfs = 0.9 * psfs / psfs.sum(dim=(-1, -2), keepdim=True)
    batch = torch.rand(2, 3, 24, 30, generator=torch.Generator().manual_seed(0))
    both = wiener_deconvolve(batch, psfs, 1e-3)
    for i in range(2):
        assert torch.allclose(both[i], wiener_deconvolve(batch[i : i + 1], psfs[i], 1e-3)[0], atol=1e-6)


def test_tuned_nsr_is_the_best_candidate_and_beats_no_compensation():
    from skimage import data
    from skimage.transform import resize

    photo = resize(data.astronaut()[100:356, 150:406], (64, 64), anti_aliasing=True)
    train = torch.tensor(photo, dtype=torch.float32).permute(2, 0, 1)[None]
    y, x = np.mgrid[-2:3, -2:3]
    disk = (x**2 + y**2 <= 4).astype(np.float64)
    psf = torch.tensor(np.repeat((0.95 * disk / disk.sum())[None], 3, axis=0), dtype=torch.float32)
    candidates = np.logspace(-5, -1, 9)
    best, scores = tune_wiener_nsr(train, psf, project, candidates)
    assert set(scores) == {float(c) for c in candidates}
    assert scores[best] == max(scores.values())
    uncompensated = float(psnr(project(train, psf[None]), train).mean())
    # Clipping to [0, 1] limits what any compensation can do; Wiener measured +0.74 dB here.
    assert scores[best] > uncompensated + 0.5
    # A callable metric with the same ordering (one image: -MSE is monotone in PSNR) picks the same NSR.
    best_mse, _ = tune_wiener_nsr(
        train, psf, project, candidates, metric=lambda p, t: -((p - t) ** 2).flatten(1).mean(1)
    )
    assert best_mse == best


def test_user_errors_are_one_line():
    with pytest.raises(EdofprojError, match="K odd"):
        WienerCompensator(np.ones((3, 4, 4)) / 16, 1e-3)
    with pytest.raises(EdofprojError, match="NSR"):
        WienerCompensator(cross_psf(), -1.0)
    with pytest.raises(EdofprojError, match="too small"):
        WienerCompensator(cross_psf(), 1e-3)(np.zeros((3, 4, 4)))
    with pytest.raises(EdofprojError, match="metric"):
        tune_wiener_nsr(torch.zeros(1, 3, 16, 16), torch.tensor(cross_psf()), project, [1e-3], metric="ssim")


def test_one_channel_psf_applies_to_every_channel():
    psf = torch.tensor(cross_psf()[:1], dtype=torch.float32)  # (1, K, K)
    batch = torch.rand(2, 3, 20, 24, generator=torch.Generator().manual_seed(3))
    assert torch.allclose(
        wiener_deconvolve(batch, psf[None], 1e-3), wiener_deconvolve(batch, psf.expand(3, 5, 5), 1e-3), atol=1e-6
    )


def test_depth_ensemble_wiener_kernel_inverts_a_blur_without_spectral_zeros():
    """With NSR 0 and one PSF whose spectrum never vanishes (and no haze), the kernel is the
    inverse filter: PSF * kernel = delta (scipy.ndimage convolution, independent of the code)."""
    psf = cross_psf(energy=1.0)[None]
    kernel = depth_ensemble_wiener_kernel(psf, 0.0, radius=24)
    for c in range(3):
        product = ndimage.convolve(np.pad(kernel[c], 4), psf[0, c], mode="constant")
        delta = np.zeros_like(product)
        delta[product.shape[0] // 2, product.shape[1] // 2] = 1.0
        np.testing.assert_allclose(product, delta, atol=1e-9)


def test_depth_ensemble_wiener_kernel_closed_forms():
    """A perfect lens (delta PSF) gives delta / (1 + NSR); the ensemble of two PSFs is
    sum conj(H) / (sum |H|^2 + 2 NSR), checked at every frequency against the two OTFs; every
    cut kernel keeps the filter's DC gain."""
    delta = np.zeros((1, 3, 5, 5))
    delta[..., 2, 2] = 1.0
    kernel = depth_ensemble_wiener_kernel(delta, 0.25, radius=3)
    expected = np.zeros((3, 7, 7))
    expected[:, 3, 3] = 1 / 1.25
    np.testing.assert_allclose(kernel, expected, atol=1e-12)

    two = np.stack([cross_psf(0.95), np.repeat(ndimage.gaussian_filter(delta[0, 0], 0.8)[None], 3, axis=0)])
    grid, nsr = 33, 0.01
    full = depth_ensemble_wiener_kernel(two, nsr, radius=16, grid=grid)  # the whole (odd) grid: nothing cut
    h = [independent_otf(p, grid, grid) for p in two]
    expected_gain = (np.conj(h[0]) + np.conj(h[1])) / (np.abs(h[0]) ** 2 + np.abs(h[1]) ** 2 + 2 * nsr)
    gain = np.fft.rfft2(np.fft.ifftshift(full, axes=(-2, -1)))
    np.testing.assert_allclose(gain, expected_gain, atol=1e-12)
    cut = depth_ensemble_wiener_kernel(two, nsr, radius=2, grid=grid)
    np.testing.assert_allclose(cut.sum(axis=(-2, -1)), expected_gain[:, 0, 0].real, atol=1e-12)
    with pytest.raises(EdofprojError, match="radius"):
        depth_ensemble_wiener_kernel(two, nsr, radius=40, grid=grid)
