"""The package as a user installs it: a wheel, in a fresh virtual environment, run from another
directory, finds its presets and runs the quick demo."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def test_the_wheel_ships_the_presets_and_runs_the_quick_demo_from_any_directory(tmp_path):
    wheels = tmp_path / "wheels"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = wheels.glob("edofproj-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {
        "edofproj/presets/cpu.yaml",
        "edofproj/presets/paper.yaml",
        "edofproj/presets/realtime.yaml",
        "edofproj/presets/cpu-realtime.yaml",
    } <= set(names)
    for run in ("cpu-doe-net", "demo-refit-axicon-net", "demo-refit-cubic-net", "demo-lens-onlineprodeb"):
        shipped = f"edofproj/builtin_runs/{run}/"
        files = ["config.yaml", "train_log.csv", "MODEL.md", "checkpoints/last.pt"]
        files += ["doe.npz"] if run != "demo-lens-onlineprodeb" else []  # the bare lens has no design file
        assert {shipped + f for f in files} <= set(names), run

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    # the dependencies (torch, ...) come from this environment; edofproj only from the wheel
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    install = subprocess.run(
        [str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert install.returncode == 0, install.stderr[-2000:]

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = subprocess.run(
        [str(python), "-c", "import edofproj; print(edofproj.__file__)"],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert str(venv) in where  # the installed copy, not the source tree
    demo = subprocess.run(
        [str(venv / "bin" / "edofproj"), "demo", "--quick", "--out", "demo"],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert demo.returncode == 0, demo.stderr[-2000:]
    assert (elsewhere / "demo" / "report.html").is_file()
