"""The DFT as matrix products (:mod:`edofproj.imaging.matrix_dft`): the same transform as torch.fft, and
the export form of the convolution and of the radial filter computes what the FFT form computes."""

from __future__ import annotations

import pytest
import torch

from edofproj.compensation.radial_filter import RadialFourierFilter
from edofproj.imaging import matrix_dft
from edofproj.imaging.convolution import convolve_same

#: (H, W, Gh, Gw): zero padding, odd, prime (one dense product) and 2-3-5-smooth lengths
SIZES = [(5, 7, 8, 9), (13, 11, 13, 11), (31, 17, 31, 17), (40, 52, 45, 64), (150, 200, 182, 232)]


@pytest.mark.parametrize("n", [1, 2, 7, 12, 182, 625, 661, 864])
def test_factor_length_splits_into_the_factor_pair_nearest_the_square_root(n):
    first, second = matrix_dft.factor_length(n)
    assert first * second == n and first <= second
    assert not any(n % d == 0 for d in range(first + 1, int(n**0.5) + 1))


@pytest.mark.parametrize("height,width,grid_h,grid_w", SIZES)
def test_rfft2_is_torch_fft2_in_the_transposed_half_layout(height, width, grid_h, grid_w):
    image = torch.rand(2, 3, height, width, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    spectrum = matrix_dft.rfft2(image, (grid_h, grid_w))
    reference = torch.fft.fft2(image, s=(grid_h, grid_w))[..., : grid_h // 2 + 1, :].transpose(-1, -2)
    assert spectrum.shape == (2, 3, 2, grid_w, grid_h // 2 + 1)
    assert torch.allclose(torch.complex(spectrum[..., 0, :, :], spectrum[..., 1, :, :]), reference, atol=1e-10)


@pytest.mark.parametrize("height,width,grid_h,grid_w", SIZES)
def test_irfft2_returns_the_requested_rows_and_columns_of_the_inverse(height, width, grid_h, grid_w):
    """A real, even transfer function G(fx, fy) applied on the half layout gives the rows and columns
    asked for of the full complex filtering."""
    image = torch.rand(1, 3, height, width, dtype=torch.float64, generator=torch.Generator().manual_seed(1))

    def gain(fx, fy):
        return 1 + 4 * fx**2 - 3 * fy**2 + 2 * (fx * fy) ** 2

    fx, fy = matrix_dft.half_spectrum_frequencies((grid_h, grid_w))
    rows, cols = (1, height - 1), (2, width)
    spectrum = matrix_dft.rfft2(image, (grid_h, grid_w)) * gain(fx.double(), fy.double())
    filtered = matrix_dft.irfft2(spectrum, (grid_h, grid_w), rows, cols)
    full_fy, full_fx = torch.fft.fftfreq(grid_h)[:, None].double(), torch.fft.fftfreq(grid_w)[None, :].double()
    reference = torch.fft.ifft2(torch.fft.fft2(image, s=(grid_h, grid_w)) * gain(full_fx, full_fy)).real
    assert filtered.shape == (1, 3, rows[1] - rows[0], cols[1] - cols[0])
    assert torch.allclose(filtered, reference[..., rows[0] : rows[1], cols[0] : cols[1]], atol=1e-10)


def test_float32_round_trip_of_a_frame_is_exact_to_a_few_units_of_1e_7():
    image = torch.rand(1, 3, 600, 800, generator=torch.Generator().manual_seed(3))
    grid = (625, 864)
    back = matrix_dft.irfft2(matrix_dft.rfft2(image, grid), grid, (0, 600), (0, 800))
    assert back.dtype == torch.float32
    assert float((back - image).abs().max()) < 5e-6


def exporting(monkeypatch):
    """Run the modules' ONNX-export branch eagerly."""
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)


def test_the_export_form_of_the_convolution_is_the_fft_convolution(monkeypatch):
    generator = torch.Generator().manual_seed(4)
    image, kernel = torch.rand(2, 3, 37, 50, generator=generator), torch.rand(1, 3, 9, 9, generator=generator)
    reference = convolve_same(image, kernel)
    exporting(monkeypatch)
    assert torch.allclose(convolve_same(image, kernel), reference, atol=2e-5)


def test_the_export_form_of_the_radial_filter_is_its_fft_form(monkeypatch):
    layer = RadialFourierFilter(channels=3, bins=8, margin_px=6).eval()
    with torch.no_grad():
        layer.gain.normal_(0, 0.2, generator=torch.Generator().manual_seed(5))
    image = torch.rand(1, 3, 29, 41, generator=torch.Generator().manual_seed(6))
    with torch.no_grad():
        reference = layer(image)
        exporting(monkeypatch)
        exported = layer(image)
    assert exported.shape == reference.shape
    assert (reference - image).abs().max() > 1e-2  # the filter does something
    assert torch.allclose(exported, reference, atol=2e-5)
