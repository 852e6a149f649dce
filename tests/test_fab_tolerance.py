"""Tolerance analysis: the as-fabricated DOE, the split-ring engine (exact for sub-ring edge shifts), the CLI."""

import copy

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.config import Config, apply_overrides
from edofproj.doe import build_doe, load_doe, save_doe
from edofproj.errors import EdofprojError
from edofproj.fabrication.masks import decompose, top_surface_m
from edofproj.fabrication.perturbation import FabricatedDOE2D, FabricatedRadialDOE, FabricationErrors
from edofproj.fabrication.profile import RadialProfile
from edofproj.fabrication.ring_engine import radial_engine_on_edges, split_ring_edges
from edofproj.fabrication.tolerance import FabricatedPSF, ToleranceSettings, energy_concentration, run_tolerance
from edofproj.optics.psf_bank import simulator_from_config

torch.set_num_threads(1)
pytestmark = pytest.mark.filterwarnings("ignore::edofproj.errors.BlurExceedsWindowWarning")  # 3x3 windows on purpose

PUPIL = 256  # 128 rings of 27.3 um
SMALL = [
    f"psf.pupil_samples={PUPIL}",
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
]
DEPTHS_M = np.array([0.35, 0.5, 0.6])


@pytest.fixture(scope="module")
def small_cfg():
    return apply_overrides(Config(), SMALL)


@pytest.fixture(scope="module")
def design(tmp_path_factory, small_cfg):
    path = tmp_path_factory.mktemp("design") / "doe.npz"
    save_doe(build_doe(small_cfg, "multifocal"), path, samples=PUPIL)
    return path


def test_as_fabricated_heights(design):
    profile = RadialProfile.from_file(design)
    masks = decompose(profile)
    r = torch.as_tensor(profile.ring_centres_m)
    nominal = FabricatedRadialDOE(profile, masks, FabricationErrors.none(4))
    np.testing.assert_allclose(nominal.height_m(r).numpy(), profile.height_m, atol=1e-15)
    # the same etch error on every mask scales every etched depth: h = top - (1 + e)(top - h_nominal)
    etched = FabricatedRadialDOE(profile, masks, FabricationErrors(np.full(4, 1.05), np.zeros((4, 2)), np.zeros(2)))
    top = top_surface_m(profile)
    np.testing.assert_allclose(etched.height_m(r).numpy(), top - 1.05 * (top - profile.height_m), atol=1e-15)
    assert etched.height_m(r).min() < 0  # physical heights: not wrapped back into one wave
    # an overlay shift moves every edge of that mask (and only those) by the shift
    shift = np.zeros((4, 2))
    shift[2, 0] = 3e-6
    moved = FabricatedRadialDOE(profile, masks, FabricationErrors(np.ones(4), shift, np.zeros(2)))
    inner_edges = masks[2].annuli_m[masks[2].annuli_m > 0]
    expected = np.unique(
        np.concatenate([m.annuli_m.reshape(-1) for i, m in enumerate(masks) if i != 2] + [inner_edges + 3e-6])
    )
    expected = expected[(expected > 0) & (expected < profile.aperture_radius_m)]
    np.testing.assert_allclose(moved.edges_m(), expected)


def test_split_rings_reproduce_the_plain_engine_on_its_own_edges(design, small_cfg):
    sim = simulator_from_config(small_cfg, window=3)
    doe = load_doe(design)
    refined = radial_engine_on_edges(sim.engine, sim.engine.ring_edges_m[1:-1])
    np.testing.assert_array_equal(refined.ring_edges_m, sim.engine.ring_edges_m)
    split = copy.copy(sim)
    split.engine = radial_engine_on_edges(sim.engine, [1e-3, 2.2e-3])
    assert len(split.engine.ring_edges_m) == len(sim.engine.ring_edges_m) + 2
    # a DOE constant on the original rings gives the same PSF on split rings (up to the engine's
    # defocus expansion error, which only shrinks on narrower rings)
    torch.testing.assert_close(split(doe, DEPTHS_M), sim(doe, DEPTHS_M), atol=1e-6, rtol=0)
    np.testing.assert_allclose(split_ring_edges([0, 1, 2], [0.5, 0.5 + 1e-12, 2.0, 3.0]), [0, 0.5, 1, 2])


def test_split_rings_are_exact_for_sub_ring_shifts(design, small_cfg):
    """Shifts of 1/8 ring: the split-ring engine at 256 samples matches the plain engine at 2048
    samples (on whose rings these shifted edges fall), while the plain 256-sample engine misses them."""
    profile = RadialProfile.from_file(design)
    masks = decompose(profile)
    fine_ring = profile.aperture_radius_m / (8 * PUPIL // 2)
    shift = np.array([[0, 0], [fine_ring, 0], [-2 * fine_ring, 0], [3 * fine_ring, 0]])
    doe = FabricatedRadialDOE(profile, masks, FabricationErrors(np.array([1.0, 1.03, 0.98, 1.01]), shift, np.zeros(2)))
    split = FabricatedPSF(small_cfg)(doe, DEPTHS_M)
    coarse = simulator_from_config(small_cfg, window=3)
    fine = simulator_from_config(apply_overrides(small_cfg, [f"psf.pupil_samples={8 * PUPIL}"]), window=3)
    reference = fine(doe, DEPTHS_M)
    assert float((split - reference).abs().max()) < 1e-5
    assert float((coarse(doe, DEPTHS_M) - reference).abs().max()) > 1e-3


def test_energy_concentration_box():
    psf = torch.zeros(2, 3, 7, 7, dtype=torch.float64)
    psf[:, :, 2:5, 2:5] = 0.01
    psf[:, :, 0, 0] = 0.5
    torch.testing.assert_close(energy_concentration(psf), torch.full((2, 3), 0.09, dtype=torch.float64))


def test_nominal_and_error_free_trials(design, small_cfg):
    profile = RadialProfile.from_file(design)
    result = run_tolerance(
        profile, small_cfg, ToleranceSettings(trials=2, etch_error_pct=0, misalignment_um=0), DEPTHS_M
    )
    plain = simulator_from_config(small_cfg, window=3)(load_doe(design), DEPTHS_M)
    np.testing.assert_allclose(result.nominal, energy_concentration(plain).mean(dim=1).numpy(), atol=1e-12)
    np.testing.assert_allclose(result.trials, np.stack([result.nominal] * 2), atol=1e-12)


def test_errors_spread_the_concentration_and_ssim_hook(design, small_cfg):
    profile = RadialProfile.from_file(design)
    calls = []

    def fake_ssim(doe, depths_m):  # stands in for a trained network's evaluation
        calls.append(doe)
        return np.full(len(depths_m), 0.9)

    settings = ToleranceSettings(trials=4, etch_error_pct=5.0, misalignment_um=1.0, seed=1)
    result = run_tolerance(profile, small_cfg, settings, DEPTHS_M, evaluate_ssim=fake_ssim)
    assert result.trials.shape == (4, 3)
    assert np.all(result.trials.std(axis=0) > 0)
    assert len(calls) == 5 and isinstance(calls[1], FabricatedRadialDOE)
    assert result.ssim_trials.shape == (4, 3)
    again = run_tolerance(profile, small_cfg, settings, DEPTHS_M)
    np.testing.assert_array_equal(again.trials, result.trials)  # seeded
    assert all(np.all(e.mask_shift_m[0] == 0) for e in result.errors)  # mask 0 is the reference


def test_2d_engine_agrees_with_the_radial_engine_on_the_nominal_design(design, small_cfg):
    profile = RadialProfile.from_file(design)
    settings = ToleranceSettings(trials=1, etch_error_pct=0, misalignment_um=0, engine="2d")
    two_d = run_tolerance(profile, small_cfg, settings, DEPTHS_M)
    radial = run_tolerance(
        profile, small_cfg, ToleranceSettings(trials=1, etch_error_pct=0, misalignment_um=0), DEPTHS_M
    )
    np.testing.assert_allclose(two_d.nominal, radial.nominal, atol=3e-3)
    # a decentred DOE is no longer radially symmetric
    masks = decompose(profile)
    decentred = FabricatedDOE2D(profile, masks, FabricationErrors(np.ones(4), np.zeros((4, 2)), np.array([50e-6, 0])))
    x = torch.tensor([50e-6 + 1e-3, 50e-6 - 1e-3], dtype=torch.float64)
    h = decentred.height_map_m(x, torch.zeros(2, dtype=torch.float64))
    assert float(h[0]) == pytest.approx(float(h[1]))  # symmetric about the shifted centre
    with pytest.raises(EdofprojError, match="2-D engine"):
        FabricatedRadialDOE(profile, masks, FabricationErrors(np.ones(4), np.zeros((4, 2)), np.array([1e-6, 0])))


def test_settings_validation(design, small_cfg):
    with pytest.raises(EdofprojError, match="needs --engine 2d"):
        ToleranceSettings(decentre_um=10).validate()
    with pytest.raises(EdofprojError, match=">= 1"):
        ToleranceSettings(trials=0).validate()
    with pytest.raises(EdofprojError, match="must be >= 0"):
        ToleranceSettings(etch_error_pct=-1).validate()
    wrong_aperture = apply_overrides(small_cfg, ["optics.aperture_mm=5"])
    with pytest.raises(EdofprojError, match="optics.aperture_mm=7"):
        run_tolerance(RadialProfile.from_file(design), wrong_aperture, ToleranceSettings(trials=1), DEPTHS_M)


def test_cli_writes_the_table_and_plot(design, tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "doe.npz").write_bytes(design.read_bytes())
    args = ["tolerance", str(run), "--trials", "3", "--depths-mm", "350:600:125", "--seed", "2"]
    for item in SMALL:
        args += ["--set", item]
    assert main(args) == 0
    assert "energy in 3x3 px" in capsys.readouterr().out
    for name in ("tolerance.csv", "tolerance.md", "tolerance.json", "tolerance.png"):
        assert (run / name).is_file()
    table = np.genfromtxt(run / "tolerance.csv", delimiter=",", names=True)
    assert table.dtype.names == ("depth_mm", "nominal", "median", "p05", "p95", "min", "max")
    np.testing.assert_allclose(table["depth_mm"], [350, 475, 600])
    assert np.all(table["p05"] <= table["median"]) and np.all(table["median"] <= table["p95"])
    assert "not computed" in (run / "tolerance.md").read_text()


def test_cli_errors(design, tmp_path, capsys):
    empty_run = tmp_path / "empty"
    empty_run.mkdir()
    assert main(["tolerance", str(empty_run)]) == 2
    assert "has no doe.npz" in capsys.readouterr().err
    assert main(["tolerance", str(design), "--decentre-um", "20", "--out", str(tmp_path / "t")]) == 2
    assert "needs --engine 2d" in capsys.readouterr().err
    assert main(["tolerance", str(design), "--trials", "0", "--out", str(tmp_path / "t")]) == 2
    assert not (tmp_path / "t").exists()
