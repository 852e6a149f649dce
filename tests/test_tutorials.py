"""The tutorials of docs/tutorials/ run: each script is executed with ``--small`` in a subprocess,
and what it wrote is checked against physics and against the library, so a tutorial that drifts
from the code fails here.

Independent checks used:
* the defocused lens at 300 mm (in focus at 500 mm, 7 mm aperture, 800 px at throw ratio 1.5) has
  the geometric blur disk of diameter ``D |1 - z/v| / q(z)`` = 11.2 px, so the central 3x3 pixels
  hold about ``9 / (pi 5.6^2)`` = 0.091 of the energy;
* one wave of fused silica at 550 nm, ``lambda / (n - 1)`` with Malitson's Sellmeier coefficients,
  and the N-level first-order efficiency ``sinc^2(1/N)``;
* the measured PSF of the virtual ProCams against the PSF the simulation used;
* the compensated preview equals the projection of the written projector image (8-bit round trip).
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"


def run_tutorial(name: str, out: Path, *extra: str) -> dict:
    """Run ``docs/tutorials/<name>.py --small --out OUT`` and return its ``summary.json``."""
    env = dict(
        os.environ,
        OMP_NUM_THREADS="1",
        PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
    )
    result = subprocess.run(
        [sys.executable, str(TUTORIALS / f"{name}.py"), "--small", "--out", str(out), *extra],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert result.returncode == 0, f"{name} failed:\n{result.stdout}\n{result.stderr}"
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def test_every_tutorial_has_a_page_that_includes_it():
    scripts = sorted(TUTORIALS.glob("*.py"))
    assert len(scripts) == 6
    index = (TUTORIALS / "index.md").read_text(encoding="utf-8")
    for script in scripts:
        page = script.with_suffix(".md")
        assert page.is_file(), f"{script.name} has no page"
        assert f'--8<-- "docs/tutorials/{script.name}"' in page.read_text(encoding="utf-8")
        assert page.name in index


def test_psf_designs(tmp_path):
    from edofproj.optics.psf_bank import PSFBank

    summary = run_tutorial("psf_designs", tmp_path)
    depths = summary["depths_mm"]
    assert depths == [300.0, 500.0, 800.0]
    for name in ("lens", "axicon", "cubic", "multifocal"):
        bank = PSFBank.load(tmp_path / f"psf_{name}.npz")
        assert tuple(bank.psf.shape) == (3, 3, 15, 15)
        energy = np.array(summary[name]["energy_in_window"])
        sharp = np.array(summary[name]["energy_3x3"])
        np.testing.assert_allclose(energy, bank.energy_in_window.mean(dim=1).numpy(), rtol=1e-6)
        assert np.all((energy > 0) & (energy <= 1 + 1e-9))
        assert np.all((sharp > 0) & (sharp <= energy + 1e-9))
    lens = np.array(summary["lens"]["energy_3x3"])
    # in focus at 500 mm: the Airy core (first zero 48 um) is far inside one 417 um pixel
    assert lens[1] > 0.95
    # at 300 mm: the geometric blur disk of 11.2 px diameter
    blur_px = 7.0 * abs(1 - 300 / 500) / (300 / (1.5 * 800))
    assert lens[0] == pytest.approx(9 / (math.pi * (blur_px / 2) ** 2), abs=0.02)
    # every extended-depth-of-field design is sharper than the lens at its worst depth, and more uniform
    for name in ("axicon", "cubic", "multifocal"):
        assert summary[name]["worst_energy_3x3"] > summary["lens"]["worst_energy_3x3"]
        assert summary[name]["spread_energy_3x3"] < summary["lens"]["spread_energy_3x3"]
    rows = (tmp_path / "psf_metrics.csv").read_text(encoding="utf-8").strip().splitlines()
    assert len(rows) == 1 + 4 * 3
    for figure in ("psf_designs.png", "sharpness_vs_depth.png"):
        assert (tmp_path / figure).stat().st_size > 10_000


#: Tutorials whose page includes the script's recorded default-size output
#: (``docs/tutorials/output/<name>.txt``, the last line -- where it wrote, the time -- left out).
RECORDED_OUTPUTS = ["psf_designs", "export_for_lithography", "procams_measure_psf", "lens_doe"]


@pytest.mark.parametrize("name", RECORDED_OUTPUTS)
def test_a_default_size_run_prints_what_its_page_shows(name, tmp_path):
    """The page's output block is the recorded file, included as it is; a fresh default-size run prints
    the same lines, each number within 1.5 units of its last printed digit (rounding across machines).
    CPU time: psf_designs about a minute (the cubic plate's 2-D engine), the others under 40 s."""
    page = (TUTORIALS / f"{name}.md").read_text(encoding="utf-8")
    assert f'--8<-- "docs/tutorials/output/{name}.txt"' in page
    env = dict(
        os.environ,
        OMP_NUM_THREADS="1",
        PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
    )
    result = subprocess.run(
        [sys.executable, str(TUTORIALS / f"{name}.py"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=3600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    printed = result.stdout.strip().splitlines()[:-1]
    recorded = (TUTORIALS / "output" / f"{name}.txt").read_text(encoding="utf-8").strip().splitlines()
    assert len(printed) == len(recorded)
    number = re.compile(r"\d+\.(\d+)")
    for fresh, shown in zip(printed, recorded):
        assert number.sub("#", fresh) == number.sub("#", shown)  # the same words and layout
        for new, old in zip(number.finditer(fresh), number.finditer(shown)):
            last_digit = 10.0 ** -len(old.group(1))
            assert abs(float(new.group(0)) - float(old.group(0))) <= 1.5 * last_digit, (fresh, shown)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("train_on_images")
    return out, run_tutorial("train_on_images", out)


def test_train_on_images(trained):
    from edofproj.runs import load_run

    out, summary = trained
    run_dir = out / "run"
    assert summary["images"] == 6 and summary["train_images"] + summary["test_images"] == 6
    assert summary["test_images"] >= 1 and summary["train_images"] >= 1
    assert summary["steps"] == 6 + 6  # the two phases
    assert summary["config_round_trip"] is True
    for key in ("loss_first_tenth", "loss_last_tenth"):
        assert math.isfinite(summary[key]) and summary[key] > 0
    assert summary["figures"] == ["doe_profile.png", "loss.png", "psf_depths.png"]
    for name in ("config.yaml", "doe.npz", "checkpoints/last.pt", "train_log.csv"):
        assert (run_dir / name).is_file()
    assert len((run_dir / "train_log.csv").read_text(encoding="utf-8").strip().splitlines()) == 1 + 12
    run = load_run(run_dir)
    assert run.step == 6 + 6 and run.doe.levels == summary["doe_levels"] == 16
    assert run.cfg.data.source == "folder"


def test_export_for_lithography(tmp_path):
    summary = run_tutorial("export_for_lithography", tmp_path)
    report = summary["report"]
    assert report["levels"] == 16 and report["masks_count"] == 4
    # one wave of fused silica at 550 nm (Malitson 1965), lambda in um
    lam = 0.55
    terms = ((0.6961663, 0.0684043), (0.4079426, 0.1162414), (0.8974794, 9.896161))
    n = math.sqrt(1 + sum(b * lam**2 / (lam**2 - c**2) for b, c in terms))
    h2pi_nm = 550.0 / (n - 1)
    assert report["h2pi_nm"] == pytest.approx(h2pi_nm, abs=0.05)
    for j, mask in enumerate(report["masks"]):
        assert mask["etch_depth_nm"] == pytest.approx(h2pi_nm / 16 * 2**j, abs=0.01)
    assert report["passes_critical_dimension"] == (summary["narrowest_um"] >= report["critical_dimension_um"])
    for row in summary["trade_off"]:
        assert row["masks"] == int(math.log2(row["levels"]))
        assert row["efficiency"] == pytest.approx(np.sinc(1 / row["levels"]) ** 2, rel=1e-9)
        assert row["narrowest_um"] > 0
    assert summary["strict_message"] and "below the critical dimension" in summary["strict_message"]
    assert summary["strict_wrote"] is False  # strict mode writes nothing
    profile = (tmp_path / "fab_16" / "profile.csv").read_text(encoding="utf-8").strip().splitlines()
    assert float(profile[-1].split(",")[0]) == pytest.approx(report["aperture_radius_um"], rel=1e-9)
    assert (tmp_path / "fab_16" / "masks.gds").stat().st_size > 0


def test_procams_measure_psf(tmp_path):
    from edofproj.optics.psf_bank import PSFBank
    from edofproj.procams import ProCamsCalibration

    summary = run_tutorial("procams_measure_psf", tmp_path)
    assert max(summary["l1_error"]) < 0.10
    np.testing.assert_allclose(summary["energy_measured"], summary["energy_true"], atol=0.01)
    assert summary["camera_map_rms_px"] < 0.05
    assert summary["mixing_matrix_max_error"] < 0.005
    measured = PSFBank.load(tmp_path / "psf_measured.npz")
    true = PSFBank.load(tmp_path / "psf_true.npz")
    assert tuple(measured.psf.shape) == tuple(true.psf.shape) == (1, 3, 15, 15)
    error = (measured.psf - true.psf).abs().sum() / true.psf.sum()
    assert float(error) < 0.10
    assert ProCamsCalibration.load(tmp_path / "calib.npz").projector_hw == (96, 128)


def check_compensation(out: Path, summary: dict) -> None:
    from edofproj.imaging import project
    from edofproj.imaging.image_io import read_image
    from edofproj.methods.designs import OpticalDesign
    from edofproj.runs import load_run

    rows = summary["rows"]
    assert rows
    for row in rows:
        for key in ("ssim_lens", "ssim_uncompensated", "ssim_compensated"):
            assert math.isfinite(row[key]) and 0 < row[key] <= 1
        assert 0 <= row["clipped_fraction"] < 1
    run = load_run(summary["run"])
    design = OpticalDesign("run", "doe", run.doe, run.cfg)
    row = rows[0]
    stem = f"{Path(row['image']).stem}_{row['depth_mm']:.0f}mm"
    emitted = read_image(out / f"projector_{stem}.png")[None]
    preview = read_image(out / f"preview_{stem}.png")[None]
    assert emitted.shape == preview.shape
    with torch.no_grad():
        shown = project(emitted, design.psf([row["depth_mm"] * 1e-3]))
    # the preview is the projection of the written projector image (up to two 8-bit roundings)
    assert float((shown - preview).abs().max()) < 3 / 255


def test_compensate_images_trains_its_own_run(tmp_path):
    summary = run_tutorial("compensate_images", tmp_path)
    assert summary["step"] == 6 + 6  # the two phases
    assert {row["depth_mm"] for row in summary["rows"]} == {300.0, 800.0}
    check_compensation(tmp_path, summary)
    assert (tmp_path / "compensation.png").stat().st_size > 10_000


def test_compensate_images_with_the_run_of_tutorial_2(trained, tmp_path):
    out, _ = trained
    summary = run_tutorial("compensate_images", tmp_path, "--run", str(out / "run"))
    check_compensation(tmp_path, summary)
