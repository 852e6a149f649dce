"""``procams evaluate``: raw captures of several methods rectified and scored against the targets."""

import csv

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.imaging.image_io import read_image_array, to_unit_float
from edofproj.procams.capture_io import write_rgb_png
from edofproj.reporting.captures import evaluate_captures
from virtual_rigs import delta_psf, exact_calibration, straight_rig

HW = (32, 40)


def gaussian_psf(sigma=1.5, window=9):
    psf = np.zeros((window, window))
    psf[window // 2, window // 2] = 1.0
    psf = gaussian_filter(psf, sigma)
    return np.stack([psf / psf.sum()] * 3)


@pytest.fixture
def session(tmp_path):
    """Two targets; captures by a sharp and a blurred rig of the same calibration."""
    sharp, blurred = straight_rig(HW, delta_psf(9)), straight_rig(HW, gaussian_psf())
    calibration = exact_calibration(sharp)
    rng = np.random.default_rng(0)
    for index in range(2):
        target = np.clip(gaussian_filter(rng.uniform(0, 1, HW + (3,)), (1, 1, 0)) * 1.6 - 0.3, 0.05, 0.95)
        write_rgb_png(tmp_path / "targets" / f"t{index}.png", target)
        target = np.round(target * 255) / 255
        light = torch.from_numpy(target.transpose(2, 0, 1).copy())[None]
        shown = calibration.to_projector_input(light)[0].numpy().transpose(1, 2, 0)  # what emits the target
        for name, rig in (("lens", blurred), ("doe+net", sharp)):
            write_rgb_png(tmp_path / "captures" / name / f"t{index}.png", rig.capture(shown, rng))
    calibration.save(tmp_path / "calib.npz")
    return tmp_path, calibration


def test_sharper_captures_score_better_and_the_report_is_written(session):
    folder, calibration = session
    result = evaluate_captures(folder / "targets", folder / "captures", calibration, folder / "report")
    assert set(result.scores) == {"lens", "doe+net"}
    sharp, blurred = result.means("doe+net"), result.means("lens")
    assert sharp["ssim"] > blurred["ssim"] + 0.1 and sharp["psnr"] > blurred["psnr"] + 3
    assert sharp["ssim"] > 0.9  # rectification undoes gamma, mixing and black level
    names = sorted(p.name for p in (folder / "report").iterdir())
    assert names == ["comparison.png", "report.html", "report.md", "scores.csv"]
    rows = list(csv.DictReader((folder / "report" / "scores.csv").open()))
    assert len(rows) == 4 and {r["method"] for r in rows} == {"lens", "doe+net"}
    markdown = (folder / "report" / "report.md").read_text()
    assert "doe+net" in markdown and "comparison.png" in markdown


def test_missing_captures_and_wrong_sizes_fail_in_one_line(session, capsys):
    folder, calibration = session
    (folder / "captures" / "doe+net" / "t1.png").unlink()
    with pytest.raises(EdofprojError, match="method 'doe\\+net' lacks captures of 1 of 2 targets: t1"):
        evaluate_captures(folder / "targets", folder / "captures", calibration, folder / "report")
    assert not (folder / "report").exists()
    code = main(
        [
            "procams",
            "evaluate",
            "--targets",
            str(folder / "targets"),
            "--captures",
            str(folder / "nothing"),
            "--calib",
            str(folder / "calib.npz"),
            "--out",
            str(folder / "report"),
        ]
    )
    assert code == 2 and "does not exist" in capsys.readouterr().err


def test_rectify_turns_raw_captures_into_the_light_of_the_targets(session):
    folder, _ = session
    assert (
        main(
            [
                "procams",
                "rectify",
                str(folder / "captures" / "doe+net"),
                "--calib",
                str(folder / "calib.npz"),
                "--out",
                str(folder / "rectified"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "procams",
                "rectify",
                str(folder / "captures" / "doe+net" / "t0.png"),
                "--calib",
                str(folder / "calib.npz"),
                "--out",
                str(folder / "one.png"),
            ]
        )
        == 0
    )
    for name in ("t0", "t1"):
        rectified = to_unit_float(read_image_array(folder / "rectified" / f"{name}.png"))
        target = to_unit_float(read_image_array(folder / "targets" / f"{name}.png"))
        assert np.abs(rectified - target).mean() < 0.02  # sharp rig: the captured light is the target's
    np.testing.assert_array_equal(
        read_image_array(folder / "one.png"), read_image_array(folder / "rectified" / "t0.png")
    )
