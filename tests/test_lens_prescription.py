"""A real lens prescription (Optiland): reading, the wavefront's sign, the cross-check with Optiland's FFT PSF."""

from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from edofproj.config import Config, ConfigError, OpticsConfig
from edofproj.errors import EdofprojError
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.lens_prescription import (
    LensPupil,
    check_aperture_matches,
    lens_pupil,
    load_prescription,
    projector_to_lens_field,
    pupil_grid,
)

HAVE_OPTILAND = importlib.util.find_spec("optiland") is not None
needs_optiland = pytest.mark.skipif(
    not HAVE_OPTILAND, reason="Optiland is not installed: pip install 'edofproj[lens]' (it is in the dev extra)"
)
BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "lens_crosscheck.py"


def _cooke():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from optiland.samples.objectives import CookeTriplet

        return CookeTriplet()


def _bench():
    spec = importlib.util.spec_from_file_location("lens_crosscheck", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@needs_optiland
@pytest.mark.parametrize("suffix", [".zmx", ".json"])
def test_a_written_prescription_reads_back_as_the_same_lens(tmp_path, suffix):
    from optiland.fileio import save_optiland_file, save_zemax_file

    lens = _cooke()
    path = tmp_path / f"cooke{suffix}"
    (save_zemax_file if suffix == ".zmx" else save_optiland_file)(lens, str(path))
    read = load_prescription(path)
    a = lens_pupil(lens, (0.0, 1.0), [550.0], 24)
    b = lens_pupil(read, (0.0, 1.0), [550.0], 24)
    assert np.isfinite(a.opd_um).sum() > 300
    np.testing.assert_allclose(b.opd_um, a.opd_um, atol=1e-9)
    np.testing.assert_allclose(b.intensity, a.intensity, atol=1e-12)


def test_unreadable_prescriptions_are_refused_in_one_line(tmp_path):
    with pytest.raises(EdofprojError, match="unknown format '.txt'"):
        load_prescription(tmp_path / "lens.txt")
    with pytest.raises(EdofprojError, match="does not exist"):
        load_prescription(tmp_path / "lens.zmx")
    if HAVE_OPTILAND:
        bad = tmp_path / "bad.json"
        bad.write_text("{not json")
        with pytest.raises(EdofprojError, match="cannot read lens prescription") as err:
            load_prescription(bad)
        assert "\n" not in str(err.value)


@needs_optiland
def test_moving_the_image_plane_is_the_engine_defocus_of_the_conjugate_screen():
    """Closed form: moving the lens's image plane (the DMD side) away by delta is, to first order,
    a screen at 1/z = 1/v - delta/f^2, whose engine defocus is W = r^2 (1/z - 1/v)/2 =
    -delta (R/f)^2 rho^2 / 2. The lens's W = -OPD must carry that sign and size."""
    lens = _cooke()
    f, epd = float(lens.paraxial.f2()), float(lens.paraxial.EPD())
    base = lens_pupil(lens, (0.0, 0.0), [550.0], 48)
    delta_mm = 0.05
    thickness = float(lens.surfaces.surfaces[6].thickness)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens.set_thickness(thickness + delta_mm, 6)
    moved = lens_pupil(lens, (0.0, 0.0), [550.0], 48)
    dw = moved.opd_um[0] - base.opd_um[0]
    px, py = pupil_grid(48)
    ok = np.isfinite(dw)
    fit = np.linalg.lstsq(np.stack([np.ones(ok.sum()), (px**2 + py**2)[ok]], 1), dw[ok], rcond=None)[0]
    expected_um = -delta_mm * 1e3 * (epd / 2 / f) ** 2 / 2
    assert fit[1] == pytest.approx(expected_um, rel=0.02)


def test_an_unaberrated_fully_transmitting_lens_pupil_is_the_thin_lens():
    """Zero OPD and uniform intensity: the engine's PSF is the ideal thin lens's at every depth
    (uniform absorption changes nothing: PSFs are fractions of the transmitted light)."""
    S = 64
    inside = np.add(*(c**2 for c in pupil_grid(S))) <= 1
    opd = np.where(inside, 0.0, np.nan)[None].repeat(2, 0)
    pupil = LensPupil(opd_um=opd, intensity=0.81 * inside[None].repeat(2, 0), wavelengths_nm=(500.0, 600.0))
    g = ProjectorGeometry(
        aperture_diameter_m=5e-3, focus_distance_m=0.8, throw_ratio=1.2, width_px=8000, height_px=6000
    )
    lams = np.array([520e-9, 580e-9])
    with torch.no_grad():
        ideal = FourierPSFEngine(g, lams, 15, S).psf(None, [0.8, 0.9])
        lensed = FourierPSFEngine(g, lams, 15, S, aberration=pupil).psf(None, [0.8, 0.9])
    torch.testing.assert_close(lensed, ideal, rtol=1e-9, atol=1e-12)


def test_a_vignetted_half_of_the_pupil_takes_its_light_out_of_the_psf():
    """Half the pupil blocked (intensity 0 for x < 0): the spot's width doubles along x only
    (a pupil half as wide), and the PSF still sums to the transmitted light."""
    S = 96
    px, py = pupil_grid(S)
    inside = px**2 + py**2 <= 1
    opd = np.where(inside, 0.0, np.nan)[None]
    half = LensPupil(opd_um=opd, intensity=(inside & (px > 0)).astype(float)[None], wavelengths_nm=(550.0,))
    g = ProjectorGeometry(
        aperture_diameter_m=5e-3, focus_distance_m=1.0, throw_ratio=2.0, width_px=8000, height_px=6000
    )
    with torch.no_grad():
        psf = FourierPSFEngine(g, [550e-9], 41, S, aberration=half).psf(None, [1.0])[0, 0].numpy()
    c = np.arange(41) - 20
    var_x = (psf.sum(0) * c**2)[np.abs(c) <= 6].sum() / psf.sum(0)[np.abs(c) <= 6].sum()
    var_y = (psf.sum(1) * c**2)[np.abs(c) <= 6].sum() / psf.sum(1)[np.abs(c) <= 6].sum()
    assert var_x > 1.5 * var_y
    assert psf.sum() == pytest.approx(1.0, abs=0.05)


def test_lens_pupil_maps_are_validated():
    with pytest.raises(EdofprojError, match="ascending wavelength"):
        LensPupil(opd_um=np.zeros((2, 4, 4)), intensity=np.ones((2, 4, 4)), wavelengths_nm=(600.0, 500.0))
    with pytest.raises(EdofprojError, match="alike"):
        LensPupil(opd_um=np.zeros((1, 4, 4)), intensity=np.ones((1, 5, 5)), wavelengths_nm=(500.0,))


def test_the_image_corner_is_the_lens_full_field():
    hxy = projector_to_lens_field([[1.0, 1.0], [1.0, 0.0], [0.0, -1.0]], 1920, 1080)
    assert math.hypot(*hxy[0]) == pytest.approx(1.0)
    assert hxy[1, 1] == 0 and hxy[2, 0] == 0 and hxy[2, 1] == pytest.approx(-1080 / math.hypot(1920, 1080))


def test_config_keys_of_a_lens_prescription_are_checked():
    with pytest.raises(ConfigError, match=r"optics.lens_field=\[1, 1\] must be \[Hx, Hy\]"):
        OpticsConfig(lens_field=[1, 1]).validate()
    with pytest.raises(ConfigError, match="must be a Zemax .zmx or an Optiland .json"):
        OpticsConfig(lens_prescription="lens.seq").validate()
    with pytest.raises(ConfigError, match="drop optics.zernike_um"):
        OpticsConfig(lens_prescription="lens.zmx", zernike_um={11: 0.05}).validate()
    OpticsConfig(lens_prescription="lens.zmx", lens_field=[0.0, 0.7]).validate()


@needs_optiland
def test_the_aperture_must_be_the_lens_entrance_pupil():
    with pytest.raises(EdofprojError, match="optics.aperture_mm=7 mm but the lens's entrance pupil is 10 mm across"):
        check_aperture_matches(_cooke(), 7.0)
    check_aperture_matches(_cooke(), 10.0)


@needs_optiland
def test_the_simulator_of_a_config_uses_the_traced_lens(tmp_path):
    from optiland.fileio import save_zemax_file

    from edofproj.optics.psf_bank import simulator_from_config

    save_zemax_file(_cooke(), str(tmp_path / "cooke.zmx"))
    cfg = Config()
    cfg.optics.lens_prescription = str(tmp_path / "cooke.zmx")
    cfg.optics.aperture_mm = 10.0
    cfg.optics.lens_field = [0.0, 0.7]
    cfg.psf.pupil_samples = 64
    sim = simulator_from_config(cfg, wavelength_nm=550.0, engine="2d", window=9)
    assert isinstance(sim.engine.aberration, LensPupil)
    assert sim.engine.aberration.field_point == (0.0, 0.7)
    assert sim.engine.aberration.rms_um(550.0) == pytest.approx(
        lens_pupil(_cooke(), (0, 0.7), [550.0], 64).rms_um(550.0)
    )


@needs_optiland
def test_lens_psf_matches_optilands_fft_psf_off_axis():
    """The engine's PSF of the Cooke triplet at 0.7 field, 550 nm, within 1 % L1 of Optiland's FFT
    PSF integrated over the same pixels (benchmarks/lens_crosscheck.py; the full table: slow tier)."""
    rows = _bench().crosscheck(_cooke(), [(0.0, 0.7)], [550.0], samples=256, rays=255, cells=8)
    assert rows[0]["l1"] < 0.01
    assert rows[0]["energy_engine"] == pytest.approx(rows[0]["energy_optiland"], abs=2e-3)


@pytest.mark.slow
@needs_optiland
def test_lens_psfs_match_optilands_fft_psf_at_three_fields_and_wavelengths():
    rows = _bench().crosscheck(
        _cooke(), [(0.0, 0.0), (0.0, 0.7), (0.0, 1.0)], [480.0, 550.0, 650.0], samples=256, rays=255, cells=8
    )
    assert len(rows) == 9
    worst = max(rows, key=lambda r: r["l1"])
    assert worst["l1"] < 0.01, worst


@needs_optiland
def test_field_points_mirrored_across_the_axis_give_mirrored_psfs():
    """A rotationally symmetric lens traced at (0, -h) and (0, +h) (projector field, through
    ``lens_field_aberrations``) gives PSFs that are each other's mirror image in y, and differ from the
    on-axis PSF (the lens's off-axis aberrations reach the simulated PSF grid)."""
    from edofproj.optics.field_psfs import field_psf_grid
    from edofproj.optics.lens_prescription import lens_field_aberrations
    from edofproj.optics.psf_bank import PSFSimulator
    from edofproj.optics.spectra import Spectrum

    S = 128
    g = ProjectorGeometry(
        aperture_diameter_m=10e-3, focus_distance_m=1.0, throw_ratio=1.58, width_px=1920, height_px=1080
    )
    field = lens_field_aberrations(_cooke(), [[0.0, -1.0], [0.0, 0.0], [0.0, 1.0]], 1920, 1080, [550.0], S)
    sim = PSFSimulator(g, Spectrum.monochromatic(550.0), 15, S, engine="2d")
    with torch.no_grad():
        grid = field_psf_grid(sim, None, [0.9], field)  # (Gy=3, Gx=1, 1, 1, K, K)
    top, centre, bottom = grid[0, 0, 0, 0], grid[1, 0, 0, 0], grid[2, 0, 0, 0]
    torch.testing.assert_close(top, torch.flip(bottom, dims=[0]), rtol=0, atol=1e-6)
    assert float((top - centre).abs().sum()) > 0.05
    assert float((top - bottom).abs().sum()) > 0.05  # the mirror is needed: coma points away from the axis


@pytest.mark.slow
@needs_optiland
def test_the_lens_tutorial_chooses_the_best_worst_case(tmp_path):
    """docs/tutorials/lens_doe.py --small: its choice is the strength with the largest worst case of
    the table it wrote, and the bare triplet is sharp at its focus (a 1080p pixel is ~5 Airy radii)."""
    import csv
    import json
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(root / "src"))
    result = subprocess.run(
        [sys.executable, str(root / "docs" / "tutorials" / "lens_doe.py"), "--small", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    rows = list(csv.DictReader((tmp_path / "lens_doe_metrics.csv").open(encoding="utf-8")))
    worst: dict[float, float] = {}
    for r in rows:
        a = float(r["alpha_waves"])
        worst[a] = min(worst.get(a, 1.0), float(r["energy_3x3"]))
    assert summary["chosen_alpha_waves"] == max(worst, key=lambda a: worst[a])
    focus = [float(r["energy_3x3"]) for r in rows if float(r["alpha_waves"]) == 0 and float(r["depth_mm"]) == 1000]
    assert min(focus) > 0.9
    assert summary["entrance_pupil_mm"] == pytest.approx(10.0)


def test_without_optiland_a_prescription_is_refused_with_the_install_hint(tmp_path, monkeypatch):
    import sys

    lens = tmp_path / "lens.zmx"
    lens.write_text("VERS 240000 3 0\n")
    monkeypatch.setitem(sys.modules, "optiland", None)  # import optiland -> ImportError
    with pytest.raises(EdofprojError, match=r"needs Optiland, which is not installed: install the lens extra"):
        load_prescription(lens)


@needs_optiland
def test_a_vignetted_lens_matches_optiland_and_its_blocked_rays_do_not_count_in_the_sampling():
    """A 6 mm clear semi-aperture on the triplet's last surface blocks 17 % of the pupil at full
    field. The blocked rays carry no light, so their OPD must not make phase steps for the engine's
    sampling check (before: an 11-rad step at the blocked edge, and the sampling search ran to its
    limit); the PSF stays within 1 % L1 of Optiland's."""
    from optiland.physical_apertures import RadialAperture

    lens = _cooke()
    lens.surfaces.surfaces[6].aperture = RadialAperture(r_max=6.0)
    pupil = lens_pupil(lens, (0.0, 1.0), [550.0], 128)
    inside = np.add(*(c**2 for c in pupil_grid(128))) <= 1
    blocked = inside & (pupil.intensity[0] == 0)
    assert 0.1 < blocked.sum() / inside.sum() < 0.3
    g = ProjectorGeometry(
        aperture_diameter_m=10e-3, focus_distance_m=1.0, throw_ratio=1.58, width_px=1920, height_px=1080
    )
    engine = FourierPSFEngine(g, [550e-9], 15, 128, aberration=pupil)
    assert engine.aberration_step_rad(128) < math.pi / 2
    rows = _bench().crosscheck(lens, [(0.0, 1.0)], [550.0], samples=256, rays=255, cells=8)
    assert rows[0]["l1"] < 0.01
