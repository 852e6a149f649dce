"""Spectral sampling: trimming, the convergence check, and convergence to a 1 nm sampling."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import torch

from edofproj.config import SpectrumConfig, load_config
from edofproj.errors import SpectralSamplingWarning
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.radial_engine import RadialPSFEngine
from edofproj.optics.spectra import (
    Spectrum,
    check_spectral_sampling,
    gauss_rule,
    pupil_path_difference_m,
    reference_spd,
    sample_wavelengths_nm,
)

CFG = load_config(None)
OPD_M = pupil_path_difference_m(ProjectorGeometry(), CFG)


def _check(spectrum_cfg):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_spectral_sampling(spectrum_cfg, Spectrum.from_config(spectrum_cfg), OPD_M)
    return [str(w.message) for w in caught if issubclass(w.category, SpectralSamplingWarning)]


def test_trimming_drops_only_end_samples_below_the_power_fraction():
    cfg = SpectrumConfig(wavelength_step_nm=5.0, trim_power=1e-3)
    full = Spectrum.from_config(dataclasses.replace(cfg, trim_power=0.0))
    trimmed = Spectrum.from_config(cfg)
    lam_full, lam = full.wavelengths_m * 1e9, trimmed.wavelengths_m * 1e9
    assert 400 < lam[0] and lam[-1] < 700 and np.allclose(np.diff(lam), 5.0)
    dropped = full.weights[:, (lam_full < lam[0] - 1e-6) | (lam_full > lam[-1] + 1e-6)]
    assert np.all(dropped.sum(axis=1) <= 1e-3) and np.allclose(trimmed.weights.sum(axis=1), 1.0)
    # the Gaussian primaries' samples beyond ~3.3 sigma carry < 5e-4: 460 nm (FWHM 25) keeps 425-495 at least
    assert lam[0] <= 425 and lam[-1] >= 650


def test_default_sampling_passes_and_coarse_steps_warn_with_the_step_needed():
    assert _check(CFG.spectrum) == []
    message = _check(dataclasses.replace(CFG.spectrum, wavelength_step_nm=30.0))
    assert len(message) == 1 and "wavelength_step_nm <= 10" in message[0]
    cut = _check(dataclasses.replace(CFG.spectrum, wavelength_min_nm=460.0, wavelength_max_nm=620.0))
    assert len(cut) == 1 and "cuts off" in cut[0] and "420-650 nm" in cut[0]


def test_measured_spd_files_keep_working(tmp_path):
    lam = np.arange(380.0, 721.0, 2.0)
    led = Spectrum.led(lam)
    csv = tmp_path / "spd.csv"
    np.savetxt(csv, np.c_[lam, 5 * led.weights.T], delimiter=",", header="wavelength_nm,r,g,b")
    cfg = SpectrumConfig(spd_csv=str(csv))
    measured, model = Spectrum.from_config(cfg), Spectrum.from_config(SpectrumConfig())
    assert np.allclose(measured.wavelengths_m, model.wavelengths_m)
    assert np.allclose(measured.weights, model.weights, atol=2e-3)
    assert _check(cfg) == []


def _rgb_psf(engine_for, doe, depths, spectrum: Spectrum) -> np.ndarray:
    """RGB PSFs with every wavelength on one radial grid (the shortest wavelength, 400 nm, is in
    every chunk so that the engines share their sample radii)."""
    mono = []
    lam = spectrum.wavelengths_m
    for start in range(0, len(lam), 40):
        chunk = np.concatenate([[400e-9], lam[start : start + 40]])
        with torch.no_grad():
            mono.append(engine_for(chunk).psf(doe, depths)[:, 1:])
    return np.einsum("cl,zlij->zcij", spectrum.weights, torch.cat(mono, dim=1).numpy())


@pytest.mark.slow
def test_default_step_is_within_a_tenth_of_a_percent_of_1_nm_and_20_nm_is_not():
    from edofproj.doe.factory import build_doe

    # an axicon over the whole range (the preset's tuned one is nearly a lens, whose PSFs change less with wavelength)
    cfg = load_config("cpu", ["doe.axicon_near_mm=300", "doe.axicon_far_mm=800"])
    geometry = ProjectorGeometry.from_config(cfg.optics)
    doe = build_doe(cfg, "axicon")
    depths = np.array([0.3, 0.5, 0.8])
    engine_for = lambda lam: RadialPSFEngine(geometry, lam, 17, 1024)  # noqa: E731
    fine_lam, fine_spd = reference_spd(CFG.spectrum)
    reference = _rgb_psf(engine_for, doe, depths, Spectrum(fine_lam * 1e-9, fine_spd))

    def l1(step_nm):
        spectrum = Spectrum.from_config(dataclasses.replace(CFG.spectrum, wavelength_step_nm=step_nm))
        psf = _rgb_psf(engine_for, doe, depths, spectrum)
        return float((np.abs(psf - reference).sum(axis=(-1, -2)) / reference.sum(axis=(-1, -2))).max())

    assert l1(CFG.spectrum.wavelength_step_nm) < 1e-3
    assert l1(20.0) > 1e-3  # the check's verdict on 20 nm is right
    assert sample_wavelengths_nm(400, 700, 10).size == 31


def test_the_gauss_rule_of_a_gaussian_spd_is_gauss_hermite():
    mean, fwhm = 530.0, 35.0
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    lam = np.arange(400.0, 701.0)
    for n in (1, 2, 4):
        nodes, weights = gauss_rule(lam, np.exp(-0.5 * ((lam - mean) / sigma) ** 2), n)
        x, w = np.polynomial.hermite.hermgauss(n)  # weight exp(-x^2): lambda = mean + sqrt(2) sigma x
        assert nodes == pytest.approx(mean + np.sqrt(2) * sigma * x, abs=1e-6)
        assert weights == pytest.approx(w / np.sqrt(np.pi), abs=1e-9)


def test_the_gauss_rule_integrates_polynomials_up_to_degree_2n_minus_1_against_any_spd():
    lam = np.arange(400.0, 701.0)
    spd = np.random.default_rng(0).random(lam.size)  # an arbitrary measured SPD
    t = (lam - 550.0) / 150.0
    for n in (1, 2, 3, 5):
        nodes, weights = gauss_rule(lam, spd, n)
        for degree in range(2 * n):
            exact = spd @ t**degree / spd.sum()
            assert weights @ ((nodes - 550.0) / 150.0) ** degree == pytest.approx(exact, abs=1e-10)


def test_gauss_quadrature_gives_each_channel_its_own_nodes_and_warns_unless_its_error_is_stated():
    cfg = dataclasses.replace(CFG.spectrum, quadrature="gauss", nodes_per_primary=2)
    spectrum = Spectrum.from_config(cfg)
    assert spectrum.wavelengths_m.size == 6 and np.all(np.diff(spectrum.wavelengths_m) > 0)
    assert np.all((spectrum.weights > 0).sum(axis=1) == 2) and np.allclose(spectrum.weights.sum(axis=1), 1.0)
    message = _check(cfg)
    assert len(message) == 1 and "quadrature=uniform" in message[0] and "stated_l1_error" in message[0]
    assert _check(dataclasses.replace(cfg, stated_l1_error=0.0025)) == []


@pytest.mark.parametrize("preset", [None, "cpu", "paper", "realtime"])
def test_the_shipped_presets_print_no_spectral_warning(preset):
    cfg = load_config(preset)
    opd = pupil_path_difference_m(ProjectorGeometry.from_config(cfg.optics), cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SpectralSamplingWarning)
        check_spectral_sampling(cfg.spectrum, Spectrum.from_config(cfg.spectrum), opd)


@pytest.mark.slow
def test_the_cpu_presets_stated_error_holds_for_its_reference_design():
    from edofproj.doe.factory import build_doe

    cfg = load_config("cpu")
    geometry = ProjectorGeometry.from_config(cfg.optics)
    doe = build_doe(cfg, "builtin:cpu-doe-net")
    depths = np.array([0.275, 0.5, 0.8])
    engine_for = lambda lam: RadialPSFEngine(geometry, lam, cfg.psf.window, cfg.psf.pupil_samples)  # noqa: E731
    fine_lam, fine_spd = reference_spd(CFG.spectrum)
    keep = fine_spd.max(axis=0) > 0
    reference = _rgb_psf(engine_for, doe, depths, Spectrum(fine_lam[keep] * 1e-9, fine_spd[:, keep]))

    def l1(spectrum_cfg):
        psf = _rgb_psf(engine_for, doe, depths, Spectrum.from_config(spectrum_cfg))
        return float((np.abs(psf - reference).sum(axis=(-1, -2)) / reference.sum(axis=(-1, -2))).max())

    assert l1(cfg.spectrum) <= cfg.spectrum.stated_l1_error
    one_per_peak = dataclasses.replace(
        CFG.spectrum, wavelength_min_nm=460.0, wavelength_max_nm=620.0, wavelength_step_nm=80.0
    )
    assert l1(one_per_peak) > 5 * cfg.spectrum.stated_l1_error  # the former 460/540/620 nm: 4.8 % in green
