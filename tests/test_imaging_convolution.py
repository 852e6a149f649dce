"""FFT convolution: equals scipy's direct/FFT convolution, no wrap-around, broadcasting, gradients."""

import itertools
import subprocess
import sys

import numpy as np
import pytest
import scipy.signal
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.convolution import broadcastable, convolve_same, fast_fft_length, fft_shape


@pytest.mark.parametrize("hw, k", [((37, 50), 9), ((16, 16), 33), ((1, 7), 3), ((64, 45), 1)])
def test_matches_scipy_fftconvolve_same(hw, k):
    rng = np.random.default_rng(0)
    image = rng.random((2, 3, *hw))
    psf = rng.random((1, 3, k, k))
    out = convolve_same(torch.from_numpy(image), torch.from_numpy(psf)).numpy()
    expected = np.stack(
        [[scipy.signal.fftconvolve(image[b, c], psf[0, c], mode="same") for c in range(3)] for b in range(2)]
    )
    assert out.shape == image.shape
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_even_and_rectangular_kernels_put_pixel_k_half_on_the_source():
    # Reference: the full direct convolution cropped so that kernel pixel (Kh//2, Kw//2) is the origin.
    rng = np.random.default_rng(1)
    image, kernel = rng.random((20, 23)), rng.random((4, 7))
    full = scipy.signal.convolve2d(image, kernel, mode="full")
    expected = full[2 : 2 + 20, 3 : 3 + 23]
    out = convolve_same(torch.from_numpy(image), torch.from_numpy(kernel)).numpy()
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_no_wrap_around_at_the_borders():
    image = torch.zeros(1, 1, 32, 32, dtype=torch.float64)
    image[..., 0, 0] = 1.0  # a point in the corner
    psf = torch.ones(1, 1, 15, 15, dtype=torch.float64)
    out = convolve_same(image, psf)[0, 0]
    assert torch.allclose(out[:8, :8], torch.ones(8, 8, dtype=torch.float64))  # reach 7 px inward
    assert out[8:, :].abs().max() < 1e-12 and out[:, 8:].abs().max() < 1e-12  # nothing on the far side


def test_per_sample_and_shared_channel_psfs_broadcast():
    rng = np.random.default_rng(2)
    image = torch.from_numpy(rng.random((3, 3, 12, 14)))
    per_sample = torch.from_numpy(rng.random((3, 3, 5, 5)))
    out = convolve_same(image, per_sample)
    for b in range(3):
        np.testing.assert_allclose(out[b].numpy(), convolve_same(image[b : b + 1], per_sample[b : b + 1])[0].numpy())
    grey = torch.from_numpy(rng.random((1, 1, 5, 5)))
    np.testing.assert_allclose(
        convolve_same(image, grey).numpy(), convolve_same(image, grey.expand(1, 3, 5, 5)).numpy()
    )


def test_mismatched_batches_raise_a_one_line_error():
    with pytest.raises(EdofprojError, match="do not match"):
        convolve_same(torch.zeros(3, 3, 8, 8), torch.zeros(2, 3, 3, 3))


def test_broadcastable_follows_numpys_broadcasting_rule():
    shapes = [(), (1,), (3,), (2, 3), (1, 3), (2, 1), (4, 3), (3, 1, 1), (2, 4, 3)]
    for a, b in itertools.product(shapes, shapes):
        try:
            np.broadcast_shapes(a, b)
            expected = True
        except ValueError:
            expected = False
        assert broadcastable(a, b) == expected, (a, b)


def test_a_projection_does_not_import_sympy_or_scipy_fft():
    """A shape check through ``torch.broadcast_shapes`` imported SymPy on its first call (about a second of every
    command's first projection); the check is now the rule written out. The FFT grid's fast length is computed
    without :mod:`scipy.fft` (a third of a second to import). In a fresh process, as a command runs."""
    code = (
        "import sys, torch\n"
        "from edofproj.imaging.projection import project\n"
        "project(torch.rand(1, 3, 16, 16), torch.full((1, 3, 5, 5), 1 / 25))\n"
        "print('sympy' in sys.modules, 'scipy.fft' in sys.modules)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False False", result.stdout + result.stderr


def test_kernel_is_cast_to_the_image_dtype():
    out = convolve_same(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 3, 3, dtype=torch.float64))
    assert out.dtype == torch.float32


def test_gradients_match_finite_differences():
    image = torch.rand(1, 1, 5, 6, dtype=torch.float64, requires_grad=True)
    psf = torch.rand(1, 1, 3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(convolve_same, (image, psf))


def test_fft_sizes_are_fast_and_large_enough():
    for n in (1, 7, 97, 631, 832, 1031):
        m = fast_fft_length(n)
        assert m >= n
        factors = m
        for p in (2, 3, 5):
            while factors % p == 0:
                factors //= p
        assert factors == 1  # 5-smooth
    # a centred 33x33 kernel needs 16 zero rows/columns: 616 -> 625 = 5^4, 816 -> 864 = 2^5 3^3
    assert fft_shape((600, 800), (33, 33)) == (625, 864)


def test_fft_sizes_are_scipys_fast_real_lengths():
    """The smallest 5-smooth length, as SciPy's ``next_fast_len(n, real=True)`` finds it (SciPy is the
    reference here; the project computes it without importing :mod:`scipy.fft`)."""
    import scipy.fft

    lengths = range(1, 20001)
    assert [fast_fft_length(n) for n in lengths] == [scipy.fft.next_fast_len(n, real=True) for n in lengths]
    with pytest.raises(EdofprojError, match=">= 1"):
        fast_fft_length(0)
