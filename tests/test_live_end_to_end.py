"""The whole loop through the virtual ProCams, with the commands a lab runs:

patterns -> ``procams capture`` (virtual camera, memory display) -> ``procams calibrate`` ->
``procams estimate-psf`` -> fine-tune -> the live loop, whose compensated captures must be
closer (SSIM) to the targets than the uncompensated ones; then ``live`` and
``compensate --capture RAW --calib`` on the command line.
"""

import json

import numpy as np
import pytest
import torch

from edofproj.application.live import run_live
from edofproj.cli import main
from edofproj.config import Config, apply_overrides
from edofproj.data import build_test_images
from edofproj.imaging.image_io import read_image_array, write_image
from edofproj.optics.psf_bank import PSFBank, simulator_from_config
from edofproj.procams.calibration import ProCamsCalibration
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.devices import open_camera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text
from edofproj.procams.virtual import VirtualProCams, simulate_captures
from edofproj.runs import load_run
from edofproj.training.finetune import finetune
from edofproj.training.trainer import train
from tiny_configs import tiny_lens_trained

# captures, calibrates, trains and fine-tunes; what the network learns depends on the arithmetic
pytestmark = pytest.mark.slow

WINDOW = 21
DEPTH_M = 0.35
HW = (96, 128)


def run_cli(*args: str) -> None:
    assert main([str(a) for a in args]) == 0


@pytest.mark.arithmetic
def test_patterns_capture_calibrate_estimate_finetune_live(tmp_path, capsys):
    torch.set_num_threads(1)
    cfg = apply_overrides(Config(), tiny_lens_trained() + [f"psf.window={WINDOW}"])
    true_psf = simulator_from_config(cfg).bank(None, [DEPTH_M]).psf[0].double().numpy()

    # the virtual rig, written as a 'procams simulate' folder (a few patterns suffice for its ground truth)
    small, small_images = build_pattern_set(
        PatternSpec(width=HW[1], height=HW[0], dot_grid=(2, 2), color_levels=2, bernoulli_count=1)
    )
    for name, image in small_images.items():
        write_rgb_png(tmp_path / "small" / name, image)
    (tmp_path / "small" / MANIFEST_NAME).write_text(manifest_json_text(small))
    rig = VirtualProCams.example(HW, true_psf, seed=2, noise_sigma=0.005, depth_m=DEPTH_M)
    simulate_captures(rig, tmp_path / "small", tmp_path / "rig")

    run_cli(
        "procams",
        "patterns",
        "--width",
        HW[1],
        "--height",
        HW[0],
        "--dots",
        "6x8",
        "--color-levels",
        4,
        "--out",
        tmp_path / "pat",
    )
    camera = ["--camera", f"virtual:{tmp_path / 'rig'}", "--display", "memory"]
    run_cli("procams", "capture", "--patterns", tmp_path / "pat", "--out", tmp_path / "cap", *camera, "--depth-mm", 350)
    assert json.loads((tmp_path / "cap" / "captures.json").read_text())["complete"] is True
    run_cli(
        "procams",
        "calibrate",
        "--patterns",
        tmp_path / "pat",
        "--captures",
        tmp_path / "cap",
        "--out",
        tmp_path / "calib.npz",
    )
    run_cli(
        "procams",
        "estimate-psf",
        "--patterns",
        tmp_path / "pat",
        "--captures",
        tmp_path / "cap",
        "--calib",
        tmp_path / "calib.npz",
        "--out",
        tmp_path / "psf.npz",
        "--window",
        WINDOW,
    )
    measured = PSFBank.load(tmp_path / "psf.npz").psf[0].double().numpy()
    l1 = np.abs(measured - true_psf).sum(axis=(-1, -2)) / true_psf.sum(axis=(-1, -2))
    # shown with -s (or -rP); never past pytest's capture, into its progress line
    print(f"PSF L1 error of capture -> calibrate -> estimate against the virtual ground truth: {np.round(l1, 4)}")
    assert np.all(l1 < 0.10), l1

    train(cfg, tmp_path / "run", progress=False)
    tuned = finetune(
        tmp_path / "run", [tmp_path / "psf.npz"], tmp_path / "tuned", steps=80, lr=3e-3, batch_size=4, progress=False
    )

    calibration = ProCamsCalibration.load(tmp_path / "calib.npz")
    display = MemoryDisplay()
    targets = [(name, image.numpy().transpose(1, 2, 0)) for name, image in build_test_images(cfg.data, size=HW)[:3]]
    summary = run_live(
        load_run(tuned.run_dir).net,
        calibration,
        display,
        open_camera(camera[1], display=display, seed=5),
        targets,
        measure=True,
    )
    before, after = np.mean(summary.ssim_uncompensated), np.mean(summary.ssim_compensated)
    print(f"live SSIM against the targets: uncompensated {before:.4f}, compensated {after:.4f}")
    assert summary.frames == len(targets)
    assert after > before + 0.01, (before, after)

    # the same on the command line, and compensate on one raw capture
    write_image(tmp_path / "target.png", torch.from_numpy(targets[0][1].transpose(2, 0, 1).copy()))
    capsys.readouterr()
    run_cli(
        "live",
        tuned.run_dir,
        "--calib",
        tmp_path / "calib.npz",
        *camera,
        "--image",
        tmp_path / "target.png",
        "--frames",
        2,
    )
    out = capsys.readouterr().out
    assert "2 frames" in out and "frames/s" in out and "compensate" in out
    display.show(
        calibration.to_projector_input(torch.from_numpy(targets[0][1].transpose(2, 0, 1).copy())[None])[0]
        .numpy()
        .transpose(1, 2, 0)
    )
    write_rgb_png(tmp_path / "raw.png", open_camera(camera[1], display=display).grab())
    run_cli(
        "compensate",
        tuned.run_dir,
        "--image",
        tmp_path / "target.png",
        "--capture",
        tmp_path / "raw.png",
        "--calib",
        tmp_path / "calib.npz",
        "--out",
        tmp_path / "proj.png",
    )
    assert read_image_array(tmp_path / "proj.png").shape[:2] == HW
    write_image(tmp_path / "small.png", torch.zeros(3, 48, 64))
    assert (
        main(
            [
                "compensate",
                str(tuned.run_dir),
                "--image",
                str(tmp_path / "small.png"),
                "--capture",
                str(tmp_path / "raw.png"),
                "--calib",
                str(tmp_path / "calib.npz"),
                "--out",
                str(tmp_path / "bad.png"),
            ]
        )
        == 2
    )
    assert "calibration was made for a 96x128 projector" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()
