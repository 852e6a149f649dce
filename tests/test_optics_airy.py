"""The radial engine against closed forms of the in-focus Airy pattern and geometric defocus."""

import math

import numpy as np
import pytest
import torch
from scipy import integrate
from scipy.optimize import brentq
from scipy.special import j0, j1

from devices import DEVICES
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.radial_engine import RadialPSFEngine

LAMBDA = 550e-9


def airy_fraction_per_px2(rho_px, geometry, lam=LAMBDA):
    """Closed-form Airy intensity as a fraction of the pupil energy per square pixel:
    I = pi R^2 / (lambda T W)^2 * (2 J1(v) / v)^2, v = 2 pi R rho / (lambda T W)."""
    R, TW = geometry.aperture_radius_m, geometry.throw_width_m
    v = 2 * math.pi * R * np.asarray(rho_px, float) / (lam * TW)
    peak = math.pi * R**2 / (lam * TW) ** 2
    out = np.full(v.shape, peak)
    nz = v > 0
    out[nz] = peak * (2 * j1(v[nz]) / v[nz]) ** 2
    return out


@pytest.fixture(scope="module", params=DEVICES)
def in_focus(request):
    """The in-focus PSF computed on the CPU and, when there is one, on a CUDA GPU."""
    g = ProjectorGeometry()
    engine = RadialPSFEngine(g, [LAMBDA], window=9, pupil_samples=512, device=request.param)
    intensity = engine.radial_intensity(None, [g.focus_distance_m])[0, 0].cpu().numpy()
    psf = engine.psf(None, [g.focus_distance_m])[0, 0].cpu().numpy()
    return g, engine, intensity, psf


def test_radial_intensity_is_the_airy_pattern(in_focus):
    g, engine, intensity, _ = in_focus
    expected = airy_fraction_per_px2(engine.rho_px, g)
    assert np.max(np.abs(intensity - expected)) < 1e-9 * expected[0]


def test_first_dark_ring_at_1_22_lambda_z_over_d(in_focus):
    g, engine, intensity, _ = in_focus
    z = g.focus_distance_m
    rho_m = engine.rho_px * float(g.pixel_pitch_m(z))
    expected = 1.22 * LAMBDA * z / g.aperture_diameter_m
    window = (rho_m > 0.8 * expected) & (rho_m < 1.2 * expected)
    i = np.argmin(np.where(window, intensity, np.inf))
    # parabolic refinement of the minimum through three samples
    y0, y1, y2 = intensity[i - 1 : i + 2]
    h = rho_m[i + 1] - rho_m[i]
    found = rho_m[i] + 0.5 * h * (y0 - y2) / (y0 - 2 * y1 + y2)
    assert found == pytest.approx(expected, rel=5e-3)  # 1.22 is itself 1.2197 rounded
    assert intensity[i] < 1e-4 * intensity[0]


def test_encircled_energy_inside_first_dark_ring_is_83_8_percent(in_focus):
    g, engine, intensity, _ = in_focus
    rho = engine.rho_px
    first_zero_px = 3.8317 * g.throw_width_m * LAMBDA / (2 * math.pi * g.aperture_radius_m)
    inside = rho <= first_zero_px
    ee = integrate.trapezoid(intensity[inside] * 2 * math.pi * rho[inside], rho[inside])
    assert ee == pytest.approx(1 - j0(3.8317) ** 2 - j1(3.8317) ** 2, abs=2e-3)
    assert ee == pytest.approx(0.838, abs=2e-3)


def test_centre_pixel_energy_matches_the_integrated_airy_pattern(in_focus):
    g, _, _, psf = in_focus
    # independent: closed-form Airy integrated over the pixel square; the disk of radius 1/2
    # has the closed-form encircled energy, the four corners are integrated numerically.
    k = 2 * math.pi * g.aperture_radius_m / (LAMBDA * g.throw_width_m)
    disk = 1 - j0(k * 0.5) ** 2 - j1(k * 0.5) ** 2
    corner, _ = integrate.dblquad(
        lambda y, x: airy_fraction_per_px2(np.array([math.hypot(x, y)]), g)[0] if math.hypot(x, y) > 0.5 else 0.0,
        0,
        0.5,
        0,
        0.5,
        epsabs=1e-12,
    )
    expected = disk + 4 * corner
    assert expected == pytest.approx(0.9653, abs=1e-4)  # the figure quoted in docs/physics.md (section on energy)
    assert psf[4, 4] == pytest.approx(expected, abs=1e-5)  # cubic pixel integration (linear: 1e-4 off)


def test_energy_in_window_plus_lost_energy_is_one(in_focus):
    g, _, _, psf = in_focus
    # lost energy from the closed form: outside the inscribed disk minus what the window's corners hold
    k = 2 * math.pi * g.aperture_radius_m / (LAMBDA * g.throw_width_m)
    half = 4.5
    outside_disk = j0(k * half) ** 2 + j1(k * half) ** 2
    # corners of the window outside the inscribed disk (one quadrant, x4), closed-form integrand
    corner, _ = integrate.dblquad(
        lambda y, x: airy_fraction_per_px2(np.array([math.hypot(x, y)]), g)[0] if math.hypot(x, y) > half else 0.0,
        0,
        half,
        lambda x: math.sqrt(max(half**2 - x**2, 0.0)),
        half,
        epsabs=1e-10,
    )
    lost = outside_disk - 4 * corner
    assert psf.sum() + lost == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("depth_m", [0.3, 0.8])
def test_defocus_blur_diameter_is_geometric(geometry, depth_m):
    engine = RadialPSFEngine(geometry, [LAMBDA], window=31, pupil_samples=1024)
    intensity = engine.radial_intensity(None, [depth_m])[0, 0].numpy()
    rho = engine.rho_px
    expected_px = (
        geometry.aperture_diameter_m
        * abs(1 - depth_m / geometry.focus_distance_m)
        / float(geometry.pixel_pitch_m(depth_m))
    )
    # a uniform disk of radius a holds the energy fraction (rho / a)^2 within rho: the
    # radius holding half the energy is a / sqrt(2)
    from scipy.integrate import cumulative_trapezoid

    ee = cumulative_trapezoid(intensity * 2 * np.pi * rho, rho, initial=0.0)
    rho_half = brentq(lambda x: np.interp(x, rho, ee) - 0.5, rho[1], rho[-1])
    assert 2 * math.sqrt(2) * rho_half == pytest.approx(expected_px, rel=0.05)


def test_the_float32_engine_is_the_airy_pattern_to_float32_rounding():
    """``psf.precision: float32`` (the training's option): the in-focus intensity is the closed-form
    Airy pattern within a few float32 units of the peak (measured 9e-7), and a defocused PSF is the
    float64 one within 1e-6 in relative L1 (measured ~1e-7; the spectral quadrature's own error is
    ~6e-3)."""
    g = ProjectorGeometry()
    engine = RadialPSFEngine(g, [LAMBDA], window=9, pupil_samples=512, dtype=torch.float32)
    intensity = engine.radial_intensity(None, [g.focus_distance_m])[0, 0].double().numpy()
    expected = airy_fraction_per_px2(engine.rho_px, g)
    assert np.max(np.abs(intensity - expected)) < 5e-6 * expected[0]
    psfs = {
        dtype: RadialPSFEngine(g, [LAMBDA], window=31, pupil_samples=1024, dtype=dtype).psf(None, [0.3, 0.8]).double()
        for dtype in (torch.float64, torch.float32)
    }
    l1 = (psfs[torch.float32] - psfs[torch.float64]).abs().sum(dim=(-1, -2)) / psfs[torch.float64].sum(dim=(-1, -2))
    assert float(l1.max()) < 1e-6
