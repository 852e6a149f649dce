"""``edofproj psf``: the file contract and one-line refusals."""

import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "edofproj.cli", *args], capture_output=True, text=True)


def test_psf_file_contract(tmp_path):
    out = tmp_path / "psf.npz"
    res = run_cli(
        "psf",
        "--doe",
        "lens",
        "--depth-mm",
        "300,500",
        "--depth-mm",
        "700:800:100",
        "--window",
        "15",
        "--set",
        "psf.pupil_samples=512",
        "--set",
        "spectrum.wavelength_step_nm=100",
        "--out",
        str(out),
    )
    assert res.returncode == 0, res.stderr
    data = np.load(out)
    psf = data["psf"]
    assert psf.dtype == np.float32 and psf.shape == (4, 3, 15, 15)
    assert np.allclose(data["depths_m"], [0.3, 0.5, 0.7, 0.8])
    assert np.allclose(data["pixel_pitch_m"], data["depths_m"] / (1.5 * 800))
    assert np.allclose(data["energy_in_window"], psf.sum(axis=(-1, -2)), atol=1e-6)
    # in focus the axis pixel holds most of the light; the PSF is symmetric about it
    assert np.unravel_index(np.argmax(psf[1, 1]), (15, 15)) == (7, 7)
    assert np.allclose(psf, psf[..., ::-1, :], atol=1e-7) and np.allclose(psf, np.swapaxes(psf, -1, -2), atol=1e-7)


def test_monochromatic_psf_has_one_channel(tmp_path):
    out = tmp_path / "psf.npz"
    res = run_cli(
        "psf",
        "--doe",
        "lens",
        "--depth-mm",
        "500",
        "--wavelength-nm",
        "550",
        "--window",
        "9",
        "--set",
        "psf.pupil_samples=256",
        "--out",
        str(out),
    )
    assert res.returncode == 0, res.stderr
    assert np.load(out)["psf"].shape == (1, 1, 9, 9)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--aperture-mm", "0"], "aperture_mm"),
        (["--depth-mm", "-5"], "in [1, 100000] mm, got -5"),
        (["--window", "8"], "odd"),
        (["--window", "1"], "odd"),
        (["--wavelength-nm", "1200"], "350-1000"),
        (["--set", "optics.focus_m=3"], "did you mean"),
        (["--doe", "nonexistent.npz"], "neither a design"),
        (["--set", "spectrum.spd_csv=/nonexistent.csv"], "cannot read SPD file"),
    ],
)
def test_bad_input_one_line_exit_2_no_output(tmp_path, args, message):
    out = tmp_path / "psf.npz"
    depth = [] if "--depth-mm" in args else ["--depth-mm", "500"]
    res = run_cli("psf", *depth, *args, "--out", str(out))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in res.stderr
    assert not out.exists() and not any(tmp_path.iterdir())


def test_plot_with_a_non_symmetric_aberration_uses_the_commands_engine(tmp_path):
    out, plot = tmp_path / "psf.npz", tmp_path / "psf.png"
    res = run_cli(
        "psf",
        "--doe",
        "lens",
        "--depth-mm",
        "500",
        "--wavelength-nm",
        "550",
        "--window",
        "9",
        "--engine",
        "2d",
        "--pupil-samples",
        "128",
        "--set",
        "optics.zernike_um={6: 0.05}",
        "--out",
        str(out),
        "--plot",
        str(plot),
    )
    assert res.returncode == 0, res.stderr
    assert out.exists() and plot.stat().st_size > 0
