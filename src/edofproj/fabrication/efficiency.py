"""Scalar diffraction efficiency of an N-level (staircase) blazed profile, and its fall-off with wavelength.

One period Lambda of an N-level blazed grating has N steps of width Lambda / N; step k adds
the phase ``2 pi alpha k / N``, where ``alpha`` is the phase depth of one full wave ``h_2pi``
at the wavelength of use, relative to the design wavelength (material dispersion included):

    alpha(lambda) = (n(lambda) - 1) lambda_d / ((n(lambda_d) - 1) lambda).

The amplitude of order m is the Fourier coefficient of the staircase,

    c_m = (1/N) sum_k exp(i 2 pi alpha k / N) (1/Lambda) int_step exp(-i 2 pi m x / Lambda) dx
        = sinc(m/N) e^{-i pi m/N} (1/N) sum_k exp(i 2 pi k (alpha - m) / N),

and the geometric sum gives (sinc(x) = sin(pi x) / (pi x))

    eta_m = sinc^2(m/N) [ sin(pi (alpha - m)) / (N sin(pi (alpha - m) / N)) ]^2
          = sinc^2(m/N) [ sinc(alpha - m) / sinc((alpha - m)/N) ]^2.

At the design wavelength (alpha = 1, m = 1) it is ``sinc^2(1/N)``: 40.5 % for 2 levels,
81.1 % for 4, 95.0 % for 8, 98.7 % for 16 (Swanson 1989). For N -> inf it tends to the
continuous blazed profile's ``sinc^2(1 - alpha)`` (Sweeney & Sommargren 1995). The light
missing from the first order goes into other orders (haze, ghost foci). This is the
textbook figure for a locally periodic zone structure; the PSF simulation of a design
already contains the quantized profile and the dispersion exactly.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..optics.materials import refractive_index
from ..optics.spectra import Spectrum


def phase_depth_ratio(wavelength_m, design_wavelength_m: float, material: str = "fused_silica") -> np.ndarray:
    """``alpha(lambda) = (n(lambda) - 1) lambda_d / ((n(lambda_d) - 1) lambda)`` (1 at the design wavelength)."""
    lam = np.asarray(wavelength_m, dtype=float)
    n = refractive_index(lam, material)
    n_d = refractive_index(design_wavelength_m, material)
    return (n - 1.0) * design_wavelength_m / ((n_d - 1.0) * lam)


def multilevel_efficiency(levels: int, alpha=1.0, order: int = 1) -> np.ndarray:
    """``eta_m = sinc^2(m/N) [sinc(alpha - m) / sinc((alpha - m)/N)]^2`` of an N-level staircase.

    Where ``(alpha - m)/N`` is a non-zero integer the bracket's limit is 1 (the phase steps
    are whole waves apart)."""
    x = np.asarray(alpha, dtype=float) - order
    denominator = np.sinc(x / levels)
    safe = np.abs(denominator) > 1e-12
    bracket = np.where(safe, np.sinc(x) / np.where(safe, denominator, 1.0), 1.0)
    return np.sinc(order / levels) ** 2 * bracket**2


def continuous_efficiency(alpha, order: int = 1) -> np.ndarray:
    """Continuous blazed profile (the N -> inf limit): ``eta_m = sinc^2(alpha - m)``."""
    return np.sinc(np.asarray(alpha, dtype=float) - order) ** 2


def efficiency_spectrum(
    levels: int, wavelengths_m, design_wavelength_m: float, material: str = "fused_silica"
) -> np.ndarray:
    """First-order efficiency at each wavelength."""
    return multilevel_efficiency(levels, phase_depth_ratio(wavelengths_m, design_wavelength_m, material))


def fine_spectrum(spectrum_cfg, step_nm: float = 1.0) -> Spectrum:
    """The configured primaries' SPDs resampled every ``step_nm`` (the 30 nm simulation samples
    are too coarse to integrate 20 nm wide LED peaks)."""
    return Spectrum.from_config(
        dataclasses.replace(spectrum_cfg, quadrature="uniform", wavelength_step_nm=step_nm, trim_power=0.0)
    )


def channel_efficiency(
    levels: int, spectrum: Spectrum, design_wavelength_m: float, material: str = "fused_silica"
) -> np.ndarray:
    """SPD-weighted first-order efficiency per channel: ``eta_c = sum_k w_ck eta(lambda_k)``, (C,)."""
    eta = efficiency_spectrum(levels, spectrum.wavelengths_m, design_wavelength_m, material)
    return spectrum.weights @ eta
