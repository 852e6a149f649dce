"""`edofproj tolerance RUN` adds the compensated SSIM of the run's network under fabrication errors."""

import csv
import subprocess
import sys

import numpy as np
import pytest

from edofproj.config import Config, apply_overrides
from edofproj.training.trainer import train

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess

TINY = [
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "psf.pupil_samples=256",
    "psf.window=11",
    "psf.depth_min_mm=400",
    "psf.depth_max_mm=600",
    "doe.mlp_frequencies=5",
    "doe.mlp_hidden=8",
    "doe.mlp_layers=1",
    "net.widths=[4,8]",
    "data.crop=32",
    "train.batch_size=1",
    "train.threads=1",
    "train.steps=2",
    "train.checkpoint_every=2",
]


def test_tolerance_of_a_trained_run_reports_compensated_ssim(tmp_path):
    run_dir = tmp_path / "run"
    train(apply_overrides(Config(), TINY), run_dir, progress=False)
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "edofproj.cli",
            "tolerance",
            str(run_dir),
            "--trials",
            "2",
            "--depths-mm",
            "400,500,600",
            "--ssim-images",
            "1",
            "--misalignment-um",
            "0.5",
        ],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    with open(run_dir / "tolerance.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3
    nominal = np.array([float(r["ssim_nominal"]) for r in rows])
    assert np.all((nominal > 0) & (nominal <= 1))
    # the in-focus depth is the easiest for an (almost untrained) network
    assert nominal[1] == nominal.max()
