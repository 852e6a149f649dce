"""Lens aberrations in both engines, against closed forms (docs/physics.md "Lens aberrations")."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy import integrate

from edofproj.config import load_config
from edofproj.errors import ConfigError, EdofprojError, SamplingError
from edofproj.optics.aberrations import FieldAberrations, PupilAberration, noll_to_nm, zernike
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.optics.radial_engine import RadialPSFEngine

LAM = 550e-9
GEO = ProjectorGeometry()
R = GEO.aperture_radius_m


def test_noll_indices_follow_noll_1976():
    expected = {1: (0, 0), 2: (1, 1), 3: (1, -1), 4: (2, 0), 5: (2, -2), 6: (2, 2), 7: (3, -1), 8: (3, 1)}
    expected.update({9: (3, -3), 10: (3, 3), 11: (4, 0), 12: (4, 2), 13: (4, -2), 14: (4, 4), 15: (4, -4), 22: (6, 0)})
    assert {j: noll_to_nm(j) for j in expected} == expected


def test_zernikes_are_orthonormal_on_the_unit_disk():
    # Gauss-Legendre in rho (exact for these polynomials) x uniform in theta (exact for trig up to 2 m)
    x, w = np.polynomial.legendre.leggauss(20)
    rho, wr = (x + 1) / 2, w / 2
    theta = np.arange(64) * 2 * np.pi / 64
    rr, tt = np.meshgrid(rho, theta, indexing="ij")
    weight = (wr * rho)[:, None] * (2 * np.pi / 64) / np.pi  # area element / pi
    Z = np.stack([zernike(j, rr, tt) for j in range(1, 16)])
    gram = np.einsum("irt,jrt,rt->ij", Z, Z, np.broadcast_to(weight, rr.shape))
    assert np.allclose(gram, np.eye(15), atol=1e-12)


def _radial(geometry=GEO, window=17, aberration=None, pupil=1024):
    return RadialPSFEngine(geometry, [LAM], window, pupil, aberration=aberration)


def test_pure_defocus_equals_a_shifted_focus_in_the_radial_engine():
    c4_m = 0.3e-6  # 0.55 waves RMS of Z4
    shifted_v = 1.0 / (1.0 / GEO.focus_distance_m - 4 * math.sqrt(3) * c4_m / R**2)
    depths = np.array([0.4, 0.5, 0.6])
    aberrated = _radial(aberration=PupilAberration.from_zernike_um({4: c4_m * 1e6})).psf(None, depths)
    shifted = _radial(dataclasses.replace(GEO, focus_distance_m=shifted_v)).psf(None, depths)
    l1 = (aberrated - shifted).abs().sum(dim=(-1, -2)) / shifted.sum(dim=(-1, -2))
    assert float(l1.max()) < 2e-3


def test_pure_defocus_equals_a_shifted_focus_in_the_2d_engine():
    c4_m = -0.2e-6
    shifted_v = 1.0 / (1.0 / GEO.focus_distance_m - 4 * math.sqrt(3) * c4_m / R**2)
    depths = np.array([0.45, 0.55])
    kw = dict(window=9, pupil_samples=256)
    ab = PupilAberration.from_zernike_um({4: c4_m * 1e6})
    aberrated = FourierPSFEngine(GEO, [LAM], aberration=ab, **kw).psf(None, depths)
    shifted = FourierPSFEngine(dataclasses.replace(GEO, focus_distance_m=shifted_v), [LAM], **kw).psf(None, depths)
    assert torch.allclose(aberrated, shifted, atol=1e-9)


def test_spherical_aberration_best_focus_is_the_balancing_defocus():
    """Seidel W040 rho^4 = W040 (Z11 / (6 sqrt 5) + Z4 / (2 sqrt 3)) + const: best focus at
    1/z - 1/v = -2 W040 / R^2 (the defocus that cancels its Z4 part)."""
    w040 = 0.1 * LAM
    ab = PupilAberration.from_zernike_um({4: w040 / (2 * math.sqrt(3)) * 1e6, 11: w040 / (6 * math.sqrt(5)) * 1e6})
    engine = _radial(aberration=ab)
    expected = -2 * w040 / R**2  # 1/z - 1/v
    offsets = expected + np.linspace(-3e-3, 3e-3, 13)
    depths = 1.0 / (1.0 / GEO.focus_distance_m + offsets)
    peak = engine.radial_intensity(None, depths)[0, :, 0].numpy()  # on-axis intensity
    a, b, _ = np.polyfit(offsets, peak, 2)
    best = -b / (2 * a)
    assert best == pytest.approx(expected, rel=0.02)
    assert abs(expected) * GEO.focus_distance_m**2 > 1e-3  # a shift of more than 1 mm at 500 mm


@pytest.mark.parametrize("waves_rms", [0.02, 0.05])
def test_strehl_ratio_of_small_spherical_aberration_follows_marechal(waves_rms):
    c11_m = waves_rms * LAM
    ideal = _radial().radial_intensity(None, [GEO.focus_distance_m])[0, 0, 0]
    engine = _radial(aberration=PupilAberration.from_zernike_um({11: c11_m * 1e6}))
    strehl = float(engine.radial_intensity(None, [GEO.focus_distance_m])[0, 0, 0] / ideal)
    # the exact on-axis value, |2 int_0^1 exp(i phi(rho)) rho drho|^2, by adaptive quadrature
    phi = lambda r: 2 * math.pi * c11_m * math.sqrt(5) * (6 * r**4 - 6 * r**2 + 1) / LAM  # noqa: E731
    re = integrate.quad(lambda r: 2 * r * math.cos(phi(r)), 0, 1, epsabs=1e-13)[0]
    im = integrate.quad(lambda r: 2 * r * math.sin(phi(r)), 0, 1, epsabs=1e-13)[0]
    assert strehl == pytest.approx(re**2 + im**2, abs=2e-5)
    marechal = math.exp(-((2 * math.pi * waves_rms) ** 2))
    assert strehl == pytest.approx(marechal, abs=0.25 * (2 * math.pi * waves_rms) ** 4)


def test_tilt_moves_the_2d_psf_by_the_closed_form():
    shift_px = 1.5
    c2_m = shift_px * R / (2 * GEO.throw_width_m)  # W = 2 c2 x / R: angle 2 c2 / R, 2 c2 T W / R pixels
    engine = FourierPSFEngine(GEO, [LAM], 15, 512, aberration=PupilAberration.from_zernike_um({2: c2_m * 1e6}))
    psf = engine.psf(None, [GEO.focus_distance_m])[0, 0]
    x = torch.arange(15, dtype=psf.dtype) - 7
    assert float((psf.sum(0) * x).sum() / psf.sum()) == pytest.approx(shift_px, abs=0.02)  # along +x (columns)
    assert float((psf.sum(1) * x).sum() / psf.sum()) == pytest.approx(0.0, abs=1e-6)


def test_radial_and_2d_engines_agree_on_spherical_aberration():
    ab = PupilAberration.from_zernike_um({11: 0.15})
    depths = np.array([0.45, 0.5])
    radial = RadialPSFEngine(GEO, [LAM], 9, 1024, aberration=ab).psf(None, depths)
    fourier = FourierPSFEngine(GEO, [LAM], 9, 512, aberration=ab).psf(None, depths)
    assert float((radial - fourier).abs().sum() / radial.sum()) < 5e-3


def test_radial_engine_refuses_asymmetric_terms_and_undersampled_phase():
    with pytest.raises(EdofprojError, match="engine 2d"):
        _radial(aberration=PupilAberration.from_zernike_um({6: 0.1})).psf(None, [0.5])
    with pytest.raises(SamplingError, match="pupil_samples >="):
        _radial(aberration=PupilAberration.from_zernike_um({11: 30.0}), pupil=64).psf(None, [0.5])


def test_chromatic_table_interpolates_in_wavelength():
    ab = PupilAberration(noll=(4,), coefficients_um=np.array([[0.1, 0.3]]), wavelengths_nm=(500.0, 600.0))
    assert ab.coefficients_at_um(550.0)[0] == pytest.approx(0.2)
    assert ab.coefficients_at_um(700.0)[0] == pytest.approx(0.3)


def test_config_keys_reach_the_simulator_and_are_validated(tmp_path):
    sim = simulator_from_config(load_config(None, ["optics.zernike_um={11: 0.05}"]), wavelength_nm=550)
    assert sim.engine.aberration is not None and sim.engine.aberration.rms_um(550) == pytest.approx(0.05)
    with pytest.raises(ConfigError, match="Noll index"):
        load_config(None, ["optics.zernike_um={0: 0.05}"])
    table = tmp_path / "ab.csv"
    table.write_text("field_x,field_y,wavelength_nm,noll,coefficient_um\n0,0,550,11,0.05\n1,0,550,6,0.1\n")
    field = FieldAberrations.from_csv(table)
    assert len(field.pupils) == 2 and not field.pupils[1].radially_symmetric


def test_a_measured_wavefront_map_of_astigmatism_matches_its_zernike(tmp_path):
    from edofproj.optics.aberrations import load_wavefront_map_um

    S = 201
    u = (np.arange(S) + 0.5) / S * 2 - 1  # pixel centres spanning [-1, 1]
    yy, xx = np.meshgrid(u, u, indexing="ij")
    rho, theta = np.hypot(xx, yy), np.arctan2(yy, xx)
    opd = np.where(rho <= 1, 0.2 * zernike(6, rho, theta), np.nan)
    np.save(tmp_path / "w.npy", opd)
    measured = PupilAberration(wavefront_map_um=load_wavefront_map_um(tmp_path / "w.npy"))
    kw = dict(window=9, pupil_samples=256)
    from_map = FourierPSFEngine(GEO, [LAM], aberration=measured, **kw).psf(None, [0.5])
    from_zernike = FourierPSFEngine(GEO, [LAM], aberration=PupilAberration.from_zernike_um({6: 0.2}), **kw)
    reference = from_zernike.psf(None, [0.5])
    assert float((from_map - reference).abs().sum() / reference.sum()) < 2e-3
    with pytest.raises(EdofprojError, match="engine 2d"):
        _radial(aberration=measured).psf(None, [0.5])


def test_a_wavefront_or_reflectance_file_holds_one_numeric_array(tmp_path):
    """Both readers take their file's one numeric array through ``fileio.read_single_numeric_array``: two
    arrays or a non-numeric one are one-line errors naming the file; one array comes back unchanged."""
    from edofproj.imaging.surfaces import read_reflectance
    from edofproj.optics.aberrations import load_wavefront_map_um

    np.savez(tmp_path / "two.npz", a=np.zeros((4, 4)), b=np.zeros((4, 4)))
    np.save(tmp_path / "text.npy", np.array([["a", "b"], ["c", "d"]]))
    np.save(tmp_path / "ok.npy", np.arange(16.0).reshape(4, 4))
    with pytest.raises(EdofprojError, match="holds 2 arrays; it must hold one square 2-D array"):
        load_wavefront_map_um(tmp_path / "two.npz")
    with pytest.raises(EdofprojError, match="is not a numeric array"):
        load_wavefront_map_um(tmp_path / "text.npy")
    with pytest.raises(EdofprojError, match="holds 2 arrays; a reflectance file holds one"):
        read_reflectance(tmp_path / "two.npz", (4, 4))
    assert np.array_equal(load_wavefront_map_um(tmp_path / "ok.npy"), np.arange(16.0).reshape(4, 4))
