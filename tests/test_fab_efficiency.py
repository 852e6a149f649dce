"""Scalar diffraction efficiency of N-level profiles: closed forms, limits, and a direct Fourier check."""

import numpy as np
import pytest

from edofproj.config import Config
from edofproj.fabrication.efficiency import (
    channel_efficiency,
    continuous_efficiency,
    efficiency_spectrum,
    fine_spectrum,
    multilevel_efficiency,
    phase_depth_ratio,
)


def staircase_order_efficiency(levels, alpha, order=1, samples_per_step=2000):
    """|c_m|^2 of one period of the staircase phase 2 pi alpha floor(N x) / N, by direct summation."""
    x = (np.arange(levels * samples_per_step) + 0.5) / (levels * samples_per_step)
    phase = 2 * np.pi * alpha * np.floor(x * levels) / levels
    c = np.mean(np.exp(1j * phase) * np.exp(-2j * np.pi * order * x))
    return abs(c) ** 2


def test_design_wavelength_closed_forms():
    assert multilevel_efficiency(2) == pytest.approx(4 / np.pi**2, abs=1e-12)  # 40.5 %
    assert multilevel_efficiency(2) == pytest.approx(0.405, abs=5e-4)
    assert multilevel_efficiency(16) == pytest.approx(0.987, abs=5e-4)
    for n in (2, 4, 8, 16, 32):
        assert multilevel_efficiency(n, 1.0) == pytest.approx(np.sinc(1 / n) ** 2, abs=1e-14)


@pytest.mark.parametrize("levels", [2, 4, 16])
@pytest.mark.parametrize("alpha", [0.6, 0.85, 1.0, 1.3])
def test_formula_matches_direct_fourier_coefficient(levels, alpha):
    assert multilevel_efficiency(levels, alpha) == pytest.approx(staircase_order_efficiency(levels, alpha), abs=1e-6)


def test_other_orders_match_direct_fourier_coefficient():
    for order in (0, -1, 2):
        assert multilevel_efficiency(8, 0.8, order) == pytest.approx(
            staircase_order_efficiency(8, 0.8, order), abs=1e-6
        )


def test_continuous_limit():
    alpha = np.linspace(0.5, 1.6, 23)
    np.testing.assert_allclose(multilevel_efficiency(2**16, alpha), continuous_efficiency(alpha), atol=1e-8)
    np.testing.assert_allclose(continuous_efficiency(alpha), np.sinc(1 - alpha) ** 2)
    # N levels never beat the continuous profile
    for n in (2, 4, 8, 16):
        assert np.all(multilevel_efficiency(n, alpha) <= continuous_efficiency(alpha) + 1e-12)


def test_phase_depth_ratio_and_spectrum():
    assert phase_depth_ratio(550e-9, 550e-9) == pytest.approx(1.0)
    lam = np.linspace(400e-9, 700e-9, 61)
    alpha = phase_depth_ratio(lam, 550e-9)
    assert np.all(np.diff(alpha) < 0)  # longer wavelength, less phase
    eta = efficiency_spectrum(16, lam, 550e-9)
    assert lam[np.argmax(eta)] == pytest.approx(550e-9, abs=5e-9)
    assert eta.max() == pytest.approx(np.sinc(1 / 16) ** 2, abs=1e-4)


def test_channel_efficiency_is_spd_weighted_mean():
    spectrum = fine_spectrum(Config().spectrum)
    np.testing.assert_allclose(spectrum.weights.sum(axis=1), 1.0)
    eta_c = channel_efficiency(16, spectrum, 550e-9)
    eta = efficiency_spectrum(16, spectrum.wavelengths_m, 550e-9)
    assert eta_c.shape == (3,)
    assert np.all((eta_c >= eta.min()) & (eta_c <= eta.max()))
    # green (530 nm peak) is nearest the 550 nm design wavelength, blue (460 nm) farthest
    assert eta_c[1] > eta_c[0] > eta_c[2]
