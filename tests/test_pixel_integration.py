"""Exact pixel integration of the 2-D engine's intensity, against closed forms (docs/physics.md section 5).

The reference is the Airy pattern of the continuous disk pupil (closed form), integrated over each
pixel square by Gauss-Legendre quadrature: independent of the engine's FFT and of its sinc factors.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss
from scipy.special import j1

from edofproj.optics.aberrations import PupilAberration
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.pixel_integration import periodic_pixel_weights

LAM = 550e-9
GEO = ProjectorGeometry()
R = GEO.aperture_radius_m
PX_PER_NU = LAM * GEO.throw_width_m / GEO.aperture_diameter_m  # pixels per diffraction unit lambda T W / D


def airy_per_px2(x_px, y_px):
    """In-focus intensity of the disk pupil, fraction of the pupil energy per square pixel:
    (pi / 4) (D / (lambda T W))^2 [2 J1(pi nu) / (pi nu)]^2 (integrates to 1 over the plane)."""
    u = np.pi * np.maximum(np.hypot(x_px, y_px) / PX_PER_NU, 1e-12)
    return (np.pi / 4) / PX_PER_NU**2 * (2 * j1(u) / u) ** 2


def airy_pixels(window: int, shift_x_px: float) -> np.ndarray:
    """Airy pattern centred at (shift_x_px, 0) integrated over the pixels of a K x K window:
    20 sub-intervals per pixel and 12 Gauss-Legendre nodes in each (the pattern has about 11 cycles
    per pixel)."""
    nodes, weights = leggauss(12)
    sub = np.linspace(-0.5, 0.5, 21)
    half = np.diff(sub)[:, None] / 2
    t = ((sub[:-1, None] + sub[1:, None]) / 2 + nodes[None, :] * half).ravel()
    w = (weights[None, :] * half).ravel()
    out = np.empty((window, window))
    c = window // 2
    for i in range(window):
        for j in range(window):
            X, Y = np.meshgrid(t + j - c - shift_x_px, t + i - c)
            out[i, j] = np.einsum("ij,i,j->", airy_per_px2(X, Y), w, w)
    return out


def shifted_spot(shift_x_px: float, window: int = 7, pupil_samples: int = 512) -> np.ndarray:
    """The 2-D engine's in-focus PSF, moved by a tilt ``2 c2 T W / R`` pixels along +x."""
    c2_m = shift_x_px * R / (2 * GEO.throw_width_m)
    engine = FourierPSFEngine(
        GEO, [LAM], window, pupil_samples, aberration=PupilAberration.from_zernike_um({2: c2_m * 1e6})
    )
    return engine.psf(None, [GEO.focus_distance_m])[0, 0].numpy()


def test_pixel_weights_integrate_a_trigonometric_polynomial_exactly():
    rng = np.random.default_rng(0)
    n, kmax = 64, 31
    k = np.arange(-kmax, kmax + 1)
    c = rng.normal(size=k.size) + 1j * rng.normal(size=k.size)
    c = c + np.conj(c[::-1])  # a real function
    samples = (c[None, :] * np.exp(2j * np.pi * k[None, :] * np.arange(n)[:, None] / n)).sum(1).real
    centres, width = np.array([0.0, 3.3, -10.7, 31.9]), 2.7
    lo, hi = centres[:, None] - width / 2, centres[:, None] + width / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        integral = np.where(
            k == 0,
            hi - lo,
            (np.exp(2j * np.pi * k * hi / n) - np.exp(2j * np.pi * k * lo / n)) / (2j * np.pi * k / n),
        )
    exact = (c[None, :] * integral).sum(1).real
    assert periodic_pixel_weights(centres, n, kmax, width) @ samples == pytest.approx(exact, abs=1e-10)


def test_a_spot_on_the_edge_between_two_pixels_splits_equally():
    psf = shifted_spot(0.5)
    left, right = psf[3, 3], psf[3, 4]
    assert abs(left - right) < 1e-9 * left
    # mirror symmetry about the edge x = 0.5: column j <-> column 7 - j (the columns 1..6)
    assert np.allclose(psf[:, 1:], psf[:, 1:][:, ::-1], atol=1e-9 * left)
    assert left == pytest.approx(airy_pixels(7, 0.5)[3, 3], abs=5e-5)


@pytest.mark.parametrize("shift_px", [0.1, 0.25, 0.5])
def test_sub_pixel_shifts_match_the_airy_pattern_integrated_over_pixels(shift_px):
    psf, exact = shifted_spot(shift_px), airy_pixels(7, shift_px)
    assert np.abs(psf - exact).sum() < 1e-4
    assert psf.max() / exact.max() == pytest.approx(1.0, abs=2e-5)
