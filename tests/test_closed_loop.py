"""The one closed loop (capture -> compensate -> project) and the one FFT operator behind it."""

import numpy as np
import scipy.signal
import torch

from edofproj.compensation.closed_loop import closed_loop, flat_screen
from edofproj.compensation.constrained import BlurHazeOperator
from edofproj.imaging.convolution import apply_transfer_function, fft_shape, optical_transfer_function
from edofproj.training.end_to_end import EndToEndProjector


def impulse_psf(channels: int = 3, k: int = 5) -> torch.Tensor:
    psf = torch.zeros(1, channels, k, k)
    psf[..., k // 2, k // 2] = 1.0
    return psf


def box_psf(k: int = 5, energy: float = 0.9) -> torch.Tensor:
    return torch.full((1, 3, k, k), energy / k**2)


def test_identity_compensation_through_a_perfect_lens_shows_the_clamped_target():
    target = torch.rand(2, 3, 12, 17) * 1.4 - 0.2  # some values outside [0, 1]
    loop = closed_loop(target, flat_screen(impulse_psf()), lambda t, c: t)
    torch.testing.assert_close(loop.captured, target.clamp(0, 1))
    torch.testing.assert_close(loop.projected, target.clamp(0, 1))


def test_the_projector_emits_the_clamped_input_once():
    target = torch.rand(1, 3, 16, 16)
    out_of_range = torch.linspace(-1.0, 2.0, 16 * 16 * 3).reshape(1, 3, 16, 16)
    psf = box_psf()
    loop = closed_loop(target, flat_screen(psf), lambda t, c: out_of_range)
    assert loop.emitted.min() >= 0.0 and loop.emitted.max() <= 1.0
    # independent forward model: scipy's 'same' convolution of the clamped input plus the haze
    x = out_of_range.clamp(0, 1)[0].numpy().astype(np.float64)
    k = psf[0].numpy().astype(np.float64)
    expected = np.stack([scipy.signal.fftconvolve(x[c], k[c], mode="same") for c in range(3)])
    expected += (1 - k.sum(axis=(-1, -2)))[:, None, None] * x.mean(axis=(-1, -2), keepdims=True)
    np.testing.assert_allclose(loop.projected[0].numpy(), expected, atol=2e-6)


def test_a_capture_at_hand_skips_the_capture_step():
    calls = []

    def forward(image):
        calls.append(image)
        return image * 0.5

    target = torch.rand(1, 3, 8, 8)
    captured = torch.rand(1, 3, 8, 8)
    loop = closed_loop(target, forward, lambda t, c: c, captured=captured)
    assert len(calls) == 1  # only the projection of the compensated image
    torch.testing.assert_close(loop.projected, captured * 0.5)


def test_end_to_end_projector_runs_the_loop_with_the_camera_model():
    class FixedPSF(torch.nn.Module):
        def forward(self, depths_m):
            return impulse_psf().expand(len(depths_m), -1, -1, -1)

    net = lambda target, captured: 2.0 * target - captured  # noqa: E731  (one-step Richardson-like update)
    model = EndToEndProjector(FixedPSF(), net, noise_sigma=0.1)
    target = torch.rand(2, 3, 10, 10)
    noise = torch.randn_like(target)
    out = model(target, torch.tensor([0.4, 0.6]), noise)
    torch.testing.assert_close(out.captured, target + 0.1 * noise)
    torch.testing.assert_close(out.projected, (target - 0.1 * noise).clamp(0, 1))


def test_transfer_function_is_centred_and_haze_restores_the_dc_gain():
    psf = torch.rand(2, 3, 7, 7, dtype=torch.float64) * 0.02
    grid = (20, 24)
    plain = optical_transfer_function(psf, grid)
    hazy = optical_transfer_function(psf, grid, haze=True)
    torch.testing.assert_close(plain[..., 0, 0].real, psf.sum(dim=(-1, -2)))
    assert torch.all(hazy[..., 0, 0] == 1.0)
    torch.testing.assert_close(hazy[..., 1:, :], plain[..., 1:, :])
    # a centro-symmetric PSF has a real transfer function (no linear phase)
    symmetric = psf + psf.flip(-1, -2)
    assert optical_transfer_function(symmetric, grid).imag.abs().max() < 1e-12


def test_grid_is_large_enough_for_a_linear_convolution_and_the_adjoint_is_exact():
    image = torch.rand(1, 3, 13, 11, dtype=torch.float64)
    residual = torch.rand(1, 3, 13, 11, dtype=torch.float64)
    psf = torch.rand(1, 3, 9, 9, dtype=torch.float64)
    grid = fft_shape((13, 11), (9, 9))
    out = apply_transfer_function(image, optical_transfer_function(psf, grid), grid)
    expected = np.stack([scipy.signal.fftconvolve(image[0, c], psf[0, c], mode="same") for c in range(3)])
    np.testing.assert_allclose(out[0].numpy(), expected, atol=1e-12)
    op = BlurHazeOperator(psf / psf.sum(dim=(-1, -2), keepdim=True) * 0.8, 13, 11)
    lhs = (op(image) * residual).sum()
    rhs = (image * op.adjoint(residual)).sum()
    torch.testing.assert_close(lhs, rhs)
