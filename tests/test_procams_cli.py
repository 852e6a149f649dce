"""``edofproj procams`` end to end through files, and its one-line errors on bad input.

The session: 128x96 patterns with a 6x8 dot grid and 3^3 colour samples, captured by the
virtual ProCams (lens PSF at 350 mm, seed 1), calibrated, and the PSF measured with a 21 px
window. Measured when written: L1 0.045 against ``true_psf.npz``.
"""

import os

import cv2
import numpy as np
import pytest

from edofproj.cli import main
from edofproj.optics.psf_bank import PSFBank

WINDOW = "21"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("procams")
    patterns, captures, calib, psf = root / "patterns", root / "captures", root / "calib.npz", root / "psf.npz"
    assert (
        main(
            [
                "procams",
                "patterns",
                "--width",
                "128",
                "--height",
                "96",
                "--out",
                str(patterns),
                "--dots",
                "6x8",
                "--color-levels",
                "3",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "procams",
                "simulate",
                "--patterns",
                str(patterns),
                "--out",
                str(captures),
                "--depth-mm",
                "350",
                "--doe",
                "lens",
                "--window",
                WINDOW,
                "--seed",
                "1",
            ]
        )
        == 0
    )
    assert (
        main(["procams", "calibrate", "--patterns", str(patterns), "--captures", str(captures), "--out", str(calib)])
        == 0
    )
    assert (
        main(
            [
                "procams",
                "estimate-psf",
                "--patterns",
                str(patterns),
                "--captures",
                str(captures),
                "--calib",
                str(calib),
                "--out",
                str(psf),
                "--window",
                WINDOW,
                "--patch",
                "40",
                "--patch-psfs",
                str(root / "patches.npz"),
            ]
        )
        == 0
    )
    return root


def linked_copy(source, target, replace=None, drop=()):
    """A capture folder of symlinks to ``source`` with some files replaced (``{name: image}``) or dropped."""
    target.mkdir()
    for name in os.listdir(source):
        if name in drop:
            continue
        if replace and name in replace:
            cv2.imwrite(str(target / name), replace[name])
        else:
            os.symlink(source / name, target / name)
    return target


def run_error(capsys, argv):
    """Run the CLI expecting a user error: exit code 2 and exactly one line on stderr."""
    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: ")
    return lines[0]


def estimate_psf_args(session, captures, out) -> list[str]:
    """``procams estimate-psf`` of ``captures`` with the session's patterns and calibration."""
    return [
        "procams",
        "estimate-psf",
        "--patterns",
        str(session / "patterns"),
        "--captures",
        str(captures),
        "--calib",
        str(session / "calib.npz"),
        "--out",
        str(out),
        "--window",
        WINDOW,
    ]


def test_measured_psf_file_follows_the_psf_contract(session):
    data = np.load(session / "psf.npz")
    assert data["psf"].dtype == np.float32 and data["psf"].shape == (1, 3, 21, 21)
    np.testing.assert_allclose(data["depths_m"], [0.35])
    np.testing.assert_allclose(data["pixel_pitch_m"], [0.35 / (1.5 * 800)])  # default optics: q = z / (T W)
    np.testing.assert_allclose(data["energy_in_window"], data["psf"].sum(axis=(-1, -2)), rtol=1e-5)
    measured, truth = PSFBank.load(session / "psf.npz"), PSFBank.load(session / "captures" / "true_psf.npz")
    error = float((measured.psf - truth.psf).abs().sum() / truth.psf.sum())
    assert error < 0.10
    patches = np.load(session / "patches.npz")
    assert patches["psf"].shape == (2, 3, 21, 21) and patches["patch_centers_px"].shape == (2, 2)
    np.testing.assert_allclose(patches["psf"].mean(axis=0), data["psf"][0], atol=1e-6)


def test_calibration_file_holds_matrix_table_and_map(session):
    calib = np.load(session / "calib.npz")
    truth = np.load(session / "captures" / "ground_truth.npz")
    error = np.abs(calib["mixing_matrix"] - truth["effective_mixing_matrix"]).max()
    assert error < 0.005 * np.abs(truth["effective_mixing_matrix"]).max()
    assert calib["color_inputs"].shape == calib["color_outputs"].shape == (27, 3)
    assert calib["map_x"].shape == (96, 128)
    assert np.sqrt(np.mean((calib["map_x"] - truth["camera_map_x"]) ** 2)) < 0.15  # camera px (~0.05 projector px)


def test_missing_captures_are_named(session, tmp_path, capsys):
    captures = linked_copy(session / "captures", tmp_path / "c", drop=("color_003.png", "color_010.png"))
    message = run_error(
        capsys,
        [
            "procams",
            "calibrate",
            "--patterns",
            str(session / "patterns"),
            "--captures",
            str(captures),
            "--out",
            str(tmp_path / "calib.npz"),
        ],
    )
    assert "lacks 2 of" in message and "color_003.png, color_010.png" in message
    assert not (tmp_path / "calib.npz").exists()


def test_wrong_capture_size_says_expected_and_got(session, tmp_path, capsys):
    small = np.zeros((300, 400, 3), np.uint8)
    captures = linked_copy(session / "captures", tmp_path / "c", replace={"bernoulli_02.png": small})
    message = run_error(
        capsys,
        estimate_psf_args(session, captures, tmp_path / "psf.npz"),
    )
    assert "'bernoulli_02.png' is 300x400 pixels, expected 384x512" in message
    assert not (tmp_path / "psf.npz").exists()


def test_a_dot_grid_that_cannot_be_found_says_how_many_dots(session, tmp_path, capsys):
    black = cv2.imread(str(session / "captures" / "black.png"))
    captures = linked_copy(session / "captures", tmp_path / "c", replace={"dots.png": black})
    previous = tmp_path / "calib.npz"
    previous.write_bytes(b"an earlier calibration")
    message = run_error(
        capsys,
        [
            "procams",
            "calibrate",
            "--patterns",
            str(session / "patterns"),
            "--captures",
            str(captures),
            "--out",
            str(previous),
        ],
    )
    assert "found 0 dots in the dot-grid capture, expected 6x8 = 48" in message
    assert previous.read_bytes() == b"an earlier calibration"  # nothing overwritten on failure


def test_saturated_captures_are_warned_about(session, tmp_path):
    white = cv2.imread(str(session / "captures" / "white.png")).astype(np.float64)
    overexposed = np.clip(white * 1.6, 0, 255).astype(np.uint8)
    captures = linked_copy(session / "captures", tmp_path / "c", replace={"white.png": overexposed})
    with pytest.warns(UserWarning, match=r"'white.png': \d+\.\d % of its pixels\); saturated light"):
        assert (
            main(
                [
                    "procams",
                    "calibrate",
                    "--patterns",
                    str(session / "patterns"),
                    "--captures",
                    str(captures),
                    "--out",
                    str(tmp_path / "calib.npz"),
                ]
            )
            == 0
        )


def test_depth_must_be_known(session, tmp_path, capsys):
    captures = linked_copy(session / "captures", tmp_path / "c", drop=("captures.json",))
    message = run_error(
        capsys,
        estimate_psf_args(session, captures, tmp_path / "psf.npz"),
    )
    assert "give --depth-mm" in message


def test_other_bad_input(session, tmp_path, capsys):
    patterns = str(session / "patterns")
    assert "exists and is not empty" in run_error(
        capsys, ["procams", "patterns", "--width", "64", "--height", "48", "--dots", "4x4", "--out", patterns]
    )
    assert "window=20 must be odd" in run_error(
        capsys,
        [
            "procams",
            "estimate-psf",
            "--patterns",
            patterns,
            "--captures",
            str(session / "captures"),
            "--calib",
            str(session / "calib.npz"),
            "--out",
            str(tmp_path / "p.npz"),
            "--window",
            "20",
        ],
    )
    assert "not a calibration file" in run_error(
        capsys,
        [
            "procams",
            "estimate-psf",
            "--patterns",
            patterns,
            "--captures",
            str(session / "captures"),
            "--calib",
            str(session / "psf.npz"),
            "--out",
            str(tmp_path / "p.npz"),
        ],
    )
    assert "has no manifest.json" in run_error(
        capsys,
        [
            "procams",
            "calibrate",
            "--patterns",
            str(tmp_path),
            "--captures",
            str(session / "captures"),
            "--out",
            str(tmp_path / "c.npz"),
        ],
    )
    assert not any(tmp_path.glob("*.npz"))
