"""Frames per second of the live loop through the virtual ProCams, and the time of each stage.

The loop of ``edofproj live`` (:func:`edofproj.application.live.run_live`): show the target
through the inverse projector response, capture it with the virtual camera, rectify it into
projector space, compensate with the network, invert the response, show the result. The rig is
``VirtualProCams.example`` at the projector size (camera ``--camera-scale`` px per projector px,
``--supersampling`` sub-samples per camera pixel, the lens PSF at ``--depth-mm``), calibrated
ideally (:meth:`VirtualProCams.ideal_calibration`: the loop's cost does not depend on how the
calibration was measured). The network is that of ``--run``, or an untrained network of
``--config`` (its cost does not depend on its weights). ``capture`` is the simulation of the
optics and the camera: on a real rig it is the camera's frame time instead.

    PYTHONPATH=src python benchmarks/bench_live.py [--size 600x800] [--frames 10] [--threads 1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from edofproj.application.live import STAGES, run_live
from edofproj.compensation.registry import build_network
from edofproj.config import load_config
from edofproj.data import build_test_images
from edofproj.doe import build_doe
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.virtual import VirtualProCams
from edofproj.runs import load_run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="600x800", help="projector HEIGHTxWIDTH (600x800)")
    parser.add_argument("--frames", type=int, default=10, help="timed frames after one warm-up frame (10)")
    parser.add_argument("--run", default=None, help="a trained run (default: an untrained network of --config)")
    parser.add_argument("--config", default="realtime", help="config preset of the untrained network (realtime)")
    parser.add_argument("--depth-mm", type=float, default=400.0, help="screen depth of the lens PSF (400)")
    parser.add_argument("--window", type=int, default=21, help="PSF window (21)")
    parser.add_argument("--camera-scale", type=float, default=1.5, help="camera px per projector px (1.5)")
    parser.add_argument("--supersampling", type=int, default=2, help="sub-samples per camera pixel (2)")
    parser.add_argument("--threads", type=int, default=1, help="PyTorch threads (1)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    height, width = (int(v) for v in args.size.lower().split("x"))
    cfg = load_run(args.run).cfg if args.run else load_config(args.config)
    net = load_run(args.run).net if args.run else build_network(cfg.net).eval()
    psf = simulator_from_config(cfg, window=args.window).bank(build_doe(cfg, "lens"), [args.depth_mm * 1e-3]).psf
    rig = VirtualProCams.example(
        (height, width), psf[0].double().numpy(), camera_scale=args.camera_scale, supersampling=args.supersampling
    )
    start = time.perf_counter()
    calibration = rig.ideal_calibration()
    calibration.to_projector_input(torch.zeros(1, 3, 1, 1))
    setup_s = time.perf_counter() - start
    display = MemoryDisplay()
    camera = VirtualCamera(rig, display)
    target = build_test_images(cfg.data, size=(height, width))[0][1].numpy().transpose(1, 2, 0)
    run_live(net, calibration, display, camera, [("warm-up", target)])
    summary = run_live(net, calibration, display, camera, [("target", target)] * args.frames, measure=True)
    print(
        f"live loop, {width}x{height} projector, camera {rig.camera_hw[1]}x{rig.camera_hw[0]} "
        f"(x{args.supersampling} sub-samples), {torch.get_num_threads()} thread(s), {summary.frames} frames; "
        f"inverse-response table and camera map built in {setup_s:.2f} s"
    )
    print(f"{summary.fps:.2f} frames/s ({1e3 * summary.frame_s:.0f} ms per frame)")
    for stage, ms in summary.mean_stage_ms().items():
        note = (
            " (not in the frame time: capture + rectify of the compensated projection)" if stage not in STAGES else ""
        )
        print(f"  {stage:<17} {ms:8.1f} ms{note}")
    print(
        f"SSIM against the target (untrained network unless --run): uncompensated "
        f"{np.mean(summary.ssim_uncompensated):.4f}, compensated {np.mean(summary.ssim_compensated):.4f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
