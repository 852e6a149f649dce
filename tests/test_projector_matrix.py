"""One projector per run: every command that takes a run (or a design) simulates it with the run's
projector, never the defaults (issue 57).

Three projectors -- the paper's 800x600 at 500 mm, a 1080p pico (5 mm aperture, throw 1.2, focused
at 1.2 m, 0.8-2.5 m) and a 4K one (8 mm, throw 2, focused at 3 m, 2-6 m) -- each as a run folder
written without training (``config.yaml`` + ``doe.npz``). Each command that takes a run and simulates
its design is run in-process; its output is checked against closed forms: the pixel pitch at depth
``z`` is ``z / (T W)``, the wavelengths are the run's ``min:step:max``, the depths lie in the run's range.
Commands that load a trained run's checkpoint (evaluate, compensate, export, bench, live, finetune,
scene --run) read its configuration through :func:`edofproj.runs.load_run`; ``compensate`` and
``evaluate`` are run on each projector's run trained for one step (``trained_run``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.config import Config, apply_overrides
from edofproj.doe import build_doe, save_doe
from edofproj.runs import write_run_config

PUPIL = 256
COMMON = [
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "spectrum.trim_power=0",
    f"psf.pupil_samples={PUPIL}",
    "doe.kind=multifocal",
]

#: name -> (overrides, (near_mm, far_mm)): the training range is the PSF range.
PROJECTORS = {
    "paper-800x600": (
        [
            "psf.window=15",
            "psf.pupil_samples=384",
            "evaluation.depths_mm=[300,500,800]",
            "psf.depth_min_mm=300",
            "psf.depth_max_mm=800",
        ],
        (300.0, 800.0),
    ),
    "pico-1080p": (
        [
            "optics.aperture_mm=5",
            "optics.throw_ratio=1.2",
            "optics.focus_mm=1200",
            "optics.width_px=1920",
            "optics.height_px=1080",
            "psf.window=13",
            "psf.depth_min_mm=800",
            "psf.depth_max_mm=2500",
            "doe.multifocal_foci_mm=[900,1200,2000]",
            "evaluation.depths_mm=[800,1200,2500]",
            "evaluation.comparison_depths_mm=[1200]",
            "spectrum.wavelength_min_nm=450",
            "spectrum.wavelength_max_nm=630",
            "spectrum.wavelength_step_nm=90",
        ],
        (800.0, 2500.0),
    ),
    "4k": (
        [
            "optics.aperture_mm=8",
            "optics.throw_ratio=2.0",
            "optics.focus_mm=3000",
            "optics.width_px=3840",
            "optics.height_px=2160",
            "psf.window=21",
            "psf.depth_min_mm=2000",
            "psf.depth_max_mm=6000",
            "doe.multifocal_foci_mm=[2500,3000,5000]",
            "evaluation.depths_mm=[2000,4000,6000]",
            "evaluation.comparison_depths_mm=[3000]",
        ],
        (2000.0, 6000.0),
    ),
}


def projector_config(name: str) -> Config:
    return apply_overrides(Config(), COMMON + PROJECTORS[name][0])


def write_run(folder, cfg: Config):
    """A run folder as training leaves it, without training: ``config.yaml`` and the fabricated ``doe.npz``."""
    folder.mkdir(parents=True)
    write_run_config(folder, cfg)
    save_doe(build_doe(cfg), folder / "doe.npz", samples=cfg.psf.pupil_samples)
    return folder


@pytest.fixture(scope="module", params=sorted(PROJECTORS))
def projector_run(request, tmp_path_factory):
    name = request.param
    cfg = projector_config(name)
    return name, cfg, write_run(tmp_path_factory.mktemp(name) / "run", cfg)


def expected_wavelengths_m(cfg: Config) -> np.ndarray:
    s = cfg.spectrum
    return np.arange(s.wavelength_min_nm, s.wavelength_max_nm + 0.5, s.wavelength_step_nm) * 1e-9


def pitch_m(cfg: Config, depths_m) -> np.ndarray:
    """The closed form: q(z) = z / (T W)."""
    return np.asarray(depths_m) / (cfg.optics.throw_ratio * cfg.optics.width_px)


@pytest.mark.slow  # the matrix: three projectors, every command
def test_psf_of_a_run_is_simulated_with_the_runs_projector(projector_run, tmp_path, capsys):
    name, cfg, run = projector_run
    out = tmp_path / "psf.npz"
    assert main(["psf", "--doe", str(run), "--out", str(out)]) == 0, capsys.readouterr().err
    data = np.load(out)
    near, far = PROJECTORS[name][1]
    assert np.allclose(data["depths_m"], np.linspace(near, far, 11) * 1e-3)  # the run's range, not 300-800 mm
    assert np.allclose(data["pixel_pitch_m"], pitch_m(cfg, data["depths_m"]), rtol=1e-9)
    assert np.allclose(data["wavelengths_m"], expected_wavelengths_m(cfg))
    assert data["psf"].shape[-1] == cfg.psf.window


@pytest.mark.slow  # the matrix: three projectors, every command
def test_plot_psf_and_psf_plot_use_the_runs_projector(projector_run, tmp_path, monkeypatch, capsys):
    name, cfg, run = projector_run
    import edofproj.reporting.psf_plots as plots

    seen = []
    monkeypatch.setattr(plots, "plot_psf_comparison", lambda panels, out, title=None: seen.append(panels))
    assert main(["plot-psf", "--doe", str(run), "--out", str(tmp_path / "a.png")]) == 0, capsys.readouterr().err
    assert main(["psf", "--doe", "lens", "--config", str(run / "config.yaml"), "--out", str(tmp_path / "l.npz"),
                 "--plot", str(tmp_path / "l.png")]) == 0  # fmt: skip
    (plot_panels, psf_panels) = seen
    assert [p[0] for p in plot_panels] == ["lens", "run"]
    assert [p[0] for p in psf_panels] == ["lens"]  # the lens alone, not beside itself
    for _label, _doe, bank in plot_panels:
        assert np.allclose(bank.pixel_pitch_m, pitch_m(cfg, bank.depths_m), rtol=1e-9)
        assert np.allclose(bank.wavelengths_m, expected_wavelengths_m(cfg))


@pytest.mark.slow  # the matrix: three projectors, every command
def test_render_of_a_run_matches_its_psf(projector_run, tmp_path, capsys):
    """``render --doe RUN`` blurs with the PSF that ``psf --doe RUN`` writes at that depth (the run's projector)."""
    import torch

    from edofproj.imaging import project, read_image, write_image

    name, cfg, run = projector_run
    near, far = PROJECTORS[name][1]
    z_mm = near
    rng = np.random.default_rng(0)
    image = tmp_path / "in.png"
    write_image(str(image), torch.from_numpy(rng.random((3, 40, 48))).float(), bits=16)
    out = tmp_path / "out.png"
    assert main(["render", "--doe", str(run), "--image", str(image), "--depth-mm", f"{z_mm:g}", "--out", str(out),
                 "--bits", "16"]) == 0, capsys.readouterr().err  # fmt: skip
    psf = tmp_path / "psf.npz"
    assert main(["psf", "--doe", str(run), "--depth-mm", f"{z_mm:g}", "--out", str(psf)]) == 0
    bank = torch.from_numpy(np.load(psf)["psf"]).double()
    expected = project(read_image(str(image))[None].double(), bank)[0].clamp(0, 1).numpy()
    rendered = read_image(str(out)).numpy()
    assert np.abs(rendered - expected).max() < 2e-4  # 16-bit rounding and the PSF file's float32


@pytest.mark.slow  # the matrix: three projectors, every command
def test_tolerance_and_export_doe_use_the_runs_projector(projector_run, tmp_path, capsys):
    name, cfg, run = projector_run
    out = tmp_path / "tol"
    assert main(["tolerance", str(run), "--trials", "2", "--out", str(out)]) == 0, capsys.readouterr().err
    report = json.loads((out / "tolerance.json").read_text())
    assert np.allclose(report["depths_mm"], cfg.evaluation.depths_mm)
    # the nominal energy in the central 3x3 px equals that of the run's own PSF at each depth
    psf = tmp_path / "psf.npz"
    args = ["psf", "--doe", str(run), "--out", str(psf)]
    assert main(args + [a for z in cfg.evaluation.depths_mm for a in ("--depth-mm", f"{z:g}")]) == 0
    bank = np.load(psf)["psf"].astype(float)
    c = cfg.psf.window // 2
    centre = bank[:, :, c - 1 : c + 2, c - 1 : c + 2].sum(axis=(-1, -2)).mean(axis=1)
    assert np.allclose(report["nominal"], centre, rtol=2e-3, atol=1e-4)
    fab = tmp_path / "fab"
    assert main(["export-doe", str(run), "--out", str(fab)]) == 0, capsys.readouterr().err
    fab_report = json.loads((fab / "fab_report.json").read_text())
    assert fab_report["aperture_radius_um"] == pytest.approx(cfg.optics.aperture_mm * 500)


@pytest.fixture(scope="module")
def trained_run(projector_run, tmp_path_factory):
    """``projector_run``'s projector trained for one step (a checkpoint, so that the commands that load a
    trained run take it): a small network on small crops, nothing of the projector changed."""
    name, cfg, run = projector_run
    out = tmp_path_factory.mktemp(name) / "trained"
    small = ["train.steps=1", "train.checkpoint_every=1", "net.widths=[4,8]", "data.crop=32", "train.batch_size=1"]
    args = ["train", "--config", str(run / "config.yaml"), "--out", str(out), "--quiet"]
    assert main(args + [a for o in small + ["train.validate_every=0"] for a in ("--set", o)]) == 0
    return name, cfg, out


@pytest.mark.slow  # the matrix: three projectors, every command
def test_compensate_simulates_the_runs_projector(trained_run, tmp_path, capsys):
    """``compensate RUN --method doe --preview``: the simulated projection is the target blurred by the
    PSF that ``psf --doe RUN`` writes at that depth (the run's projector, its pitch z / (T W))."""
    import torch

    from edofproj.imaging import project, read_image, write_image

    name, cfg, run = trained_run
    z_mm = PROJECTORS[name][1][0]
    image = tmp_path / "in.png"
    write_image(str(image), torch.from_numpy(np.random.default_rng(1).random((3, 40, 48))).float(), bits=16)
    preview = tmp_path / "shown.png"
    args = ["compensate", str(run), "--method", "doe", "--image", str(image), "--depth-mm", f"{z_mm:g}"]
    assert main(args + ["--out", str(tmp_path / "o.png"), "--preview", str(preview), "--bits", "16"]) == 0
    psf = tmp_path / "psf.npz"
    assert main(["psf", "--doe", str(run), "--depth-mm", f"{z_mm:g}", "--out", str(psf)]) == 0
    data = np.load(psf)
    assert np.allclose(data["pixel_pitch_m"], pitch_m(cfg, data["depths_m"]), rtol=1e-9)
    expected = project(read_image(str(image))[None].double(), torch.from_numpy(data["psf"]).double())[0]
    assert np.abs(read_image(str(preview)).numpy() - expected.clamp(0, 1).numpy()).max() < 2e-4
    capsys.readouterr()


@pytest.mark.slow  # the matrix: three projectors, every command
def test_evaluate_scores_the_runs_depths_and_tilted_range(trained_run, tmp_path, capsys):
    import csv

    name, cfg, run = trained_run
    out = tmp_path / "eval"
    assert main(["evaluate", str(run), "--methods", "doe", "--out", str(out), "--quiet"]) == 0
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert sorted({float(r["depth_mm"]) for r in rows}) == sorted(cfg.evaluation.depths_mm)
    tilted = list(csv.DictReader((out / "tilted_metrics.csv").open()))
    near, far = PROJECTORS[name][1]
    assert {(float(r["near_mm"]), float(r["far_mm"])) for r in tilted} == {(near, far)}  # the scored range
    capsys.readouterr()


@pytest.mark.parametrize("command", ["psf", "plot-psf", "render", "tolerance", "export-doe"])
def test_a_config_of_another_projector_is_refused_with_its_differences(command, tmp_path, capsys):
    run = write_run(tmp_path / "pico", projector_config("pico-1080p"))
    out = str(tmp_path / "out")
    argv = {
        "psf": ["psf", "--doe", str(run), "--out", out + ".npz"],
        "plot-psf": ["plot-psf", "--doe", str(run), "--out", out + ".png"],
        "render": ["render", "--doe", str(run), "--image", "x.png", "--depth-mm", "900", "--out", out + ".png"],
        "tolerance": ["tolerance", str(run), "--out", out],
        "export-doe": ["export-doe", str(run), "--out", out],
    }[command]
    assert main(argv + ["--config", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "describes another projector" in err and "optics.aperture_mm (5.0 -> 7.0)" in err
    assert not list(tmp_path.glob("out*"))


def test_two_runs_of_different_projectors_are_not_compared(tmp_path, capsys):
    a = write_run(tmp_path / "a", projector_config("pico-1080p"))
    b = write_run(tmp_path / "b", projector_config("4k"))
    assert main(["plot-psf", "--doe", str(a), "--doe", str(b), "--out", str(tmp_path / "x.png")]) == 2
    assert "different projectors" in capsys.readouterr().err


def test_a_design_file_behind_another_aperture_is_refused(tmp_path, capsys):
    run = write_run(tmp_path / "pico", projector_config("pico-1080p"))
    assert main(["psf", "--doe", str(run / "doe.npz"), "--out", str(tmp_path / "p.npz")]) == 2
    assert "made for a 5 mm aperture" in capsys.readouterr().err


def test_a_design_file_without_its_projector_says_so(tmp_path, recwarn):
    from edofproj.errors import ProjectorWarning

    run = write_run(tmp_path / "paper", projector_config("paper-800x600"))
    out = str(tmp_path / "p.npz")
    assert main(["psf", "--doe", str(run / "doe.npz"), "--depth-mm", "500", "--out", out]) == 0
    assert [w for w in recwarn if issubclass(w.category, ProjectorWarning)]  # the default projector, said
    recwarn.clear()
    assert main(["psf", "--doe", str(run / "doe.npz"), "--config", str(run / "config.yaml"), "--out", out]) == 0
    assert not [w for w in recwarn if issubclass(w.category, ProjectorWarning)]


def test_render_psf_file_on_a_tilted_screen_takes_the_files_throw(tmp_path, capsys):
    """``render --psf FILE --tilt-deg``: the far edge's depth follows the throw the PSF file was simulated
    for (its pitch q(z) = z / (T W)), not the default projector's: far = near (1 + u t) / (1 - u t) with
    u = (w - 1) / (2 T W), t = tan(tilt), for the pico's T W = 1.2 x 1920."""
    import torch

    from edofproj.imaging import write_image
    from edofproj.optics.psf_bank import PSFBank, simulator_from_config

    cfg = projector_config("pico-1080p")
    bank = simulator_from_config(cfg).bank(None, [0.8, 1.6])
    assert isinstance(bank, PSFBank)
    bank.save(tmp_path / "psf.npz")
    image = tmp_path / "in.png"
    write_image(str(image), torch.full((3, 40, 48), 0.5))
    args = ["render", "--psf", str(tmp_path / "psf.npz"), "--image", str(image), "--tilt-deg", "30"]
    assert main(args + ["--near-mm", "800", "--out", str(tmp_path / "r.png")]) == 0
    u, t = (48 - 1) / (2 * 1.2 * 1920), np.tan(np.radians(30))
    assert f"800.0-{800 * (1 + u * t) / (1 - u * t):.1f} mm" in capsys.readouterr().out


def test_scene_render_and_procams_simulate_say_a_design_file_uses_the_default_projector(tmp_path, recwarn):
    import torch

    from edofproj.errors import ProjectorWarning
    from edofproj.imaging import write_image

    run = write_run(tmp_path / "paper", projector_config("paper-800x600"))
    design = str(run / "doe.npz")
    image = tmp_path / "in.png"
    write_image(str(image), torch.full((3, 24, 32), 0.5))
    scene = ["scene", "render", "--scene", "sphere_wall", "--doe", design, "--image", str(image)]
    assert main(scene + ["--out", str(tmp_path / "s.png")]) == 0
    assert [w for w in recwarn if issubclass(w.category, ProjectorWarning)]
    recwarn.clear()
    patterns = ["procams", "patterns", "--width", "32", "--height", "24", "--dots", "2x2", "--color-levels", "2"]
    assert main(patterns + ["--out", str(tmp_path / "pat")]) == 0
    # another file, so that the warning's text differs: a filter of action "default" (one a library may set
    # while the test runs) shows a warning once per text and place
    other = tmp_path / "other_doe.npz"
    other.write_bytes((run / "doe.npz").read_bytes())
    simulate = ["procams", "simulate", "--patterns", str(tmp_path / "pat"), "--depth-mm", "500", "--doe", str(other)]
    assert main(simulate + ["--out", str(tmp_path / "cap")]) == 0
    assert [w for w in recwarn if issubclass(w.category, ProjectorWarning)]
