"""The pipelined live loop at 600x800: stage times, throughput and latency, in two set-ups.

The loop of ``edofproj live`` (:func:`edofproj.application.live.run_live`): show the target
through the inverse projector response, capture it, rectify it into projector space, compensate
with the network, invert the response, show the result -- display, camera and compute in their
own threads. The network is that of ``--run``, or an untrained network of ``--config`` (the
``realtime`` preset; its cost does not depend on its weights). The rig is
``VirtualProCams.example`` at the projector size (camera ``--camera-scale`` px per projector px,
``--supersampling`` sub-samples per camera pixel, lens PSF at ``--depth-mm``), calibrated
ideally (:meth:`VirtualProCams.ideal_calibration`; the loop's cost does not depend on how the
calibration was measured).

1. **instant camera**: an in-memory display and a camera that returns a ready frame (one
   virtual capture of the target, made before timing): what the loop costs around the network.
   Targets: >= 30 frames/s; the ``compensate`` stage (the network alone) within 20 % of the
   network's time as ``edofproj bench`` measures it (same process, same threads, printed).
2. **virtual ProCams**: the camera simulates the optics and the sensor for every frame (on a real
   rig that is the camera's frame time). Target: frames/s >= 1 / (capture + 10 ms).

Each prints a table: stage, median ms, 99th percentile ms; throughput; latency (target taken ->
compensated frame on screen, median and 99th percentile).

    PYTHONPATH=src python benchmarks/bench_live.py [--size 600x800] [--frames 60] [--virtual-frames 8]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from edofproj.application.live import STAGES, LiveSummary, run_live
from edofproj.compensation.registry import build_network
from edofproj.config import load_config
from edofproj.data import build_test_images
from edofproj.doe import build_doe
from edofproj.evaluation.timing import measure_ms, network_torch_case
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.procams.devices.base import Camera
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.virtual import VirtualProCams
from edofproj.runs import load_run

OUTSIDE_NETWORK = ("rectify", "to_input")
"""The per-frame work of the compute thread besides the network (the display's and camera's own
time runs in their threads and is listed separately)."""


class InstantCamera(Camera):
    """Returns the same ready frame at once: a camera that costs nothing."""

    spec = "instant"

    def __init__(self, frame: np.ndarray) -> None:
        self.frame = frame

    def grab(self) -> np.ndarray:
        return self.frame


def print_summary(title: str, summary: LiveSummary) -> None:
    print(f"\n{title}: {summary.frames} frames")
    print(f"  {'stage':<17} {'median ms':>10} {'p99 ms':>8}")
    stats = summary.stage_ms()
    for stage in STAGES + ("check",):
        if stage in stats:
            print(f"  {stage:<17} {stats[stage][0]:10.2f} {stats[stage][1]:8.2f}")
    outside = sum(stats[s][0] for s in OUTSIDE_NETWORK)
    print(f"  outside the network (rectify + to_input): {outside:.2f} ms per frame (median sums)")
    median, p99 = summary.latency_ms()
    print(f"  throughput {summary.fps:.1f} frames/s; latency median {median:.1f} ms, p99 {p99:.1f} ms")
    if summary.stalls:
        print(f"  camera stalls: {summary.stalls}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="600x800", help="projector HEIGHTxWIDTH (600x800)")
    parser.add_argument("--frames", type=int, default=60, help="timed frames with the instant camera (60)")
    parser.add_argument("--virtual-frames", type=int, default=8, help="timed frames through the virtual ProCams (8)")
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
    _ = calibration.rectifier, calibration.inverse_table
    setup_s = time.perf_counter() - start
    target = build_test_images(cfg.data, size=(height, width))[0][1].numpy().transpose(1, 2, 0).copy()
    print(
        f"live loop, {width}x{height} projector, camera {rig.camera_hw[1]}x{rig.camera_hw[0]} "
        f"(x{args.supersampling} sub-samples), {torch.get_num_threads()} PyTorch thread(s), network "
        f"'{args.run or args.config}'; calibration tables built in {setup_s:.2f} s "
        f"(inverse response: {type(calibration.inverse_table).__name__})"
    )

    # 1. instant camera: one virtual capture of the target, returned at once
    display = MemoryDisplay()
    display.show(calibration.inverse_table.apply(torch.from_numpy(target)).numpy())
    frame = VirtualCamera(rig, display).grab()
    camera = InstantCamera(frame)
    run_live(net, calibration, MemoryDisplay(), camera, [("warm-up", target)] * 3)
    instant = run_live(net, calibration, MemoryDisplay(), camera, [("target", target)] * args.frames)
    print_summary("instant camera, in-memory display", instant)
    bench_frame = network_torch_case(net, "net").build(height, width)
    bench_ms = float(np.median(measure_ms(bench_frame, repeats=max(10, args.frames // 2), warmup=2)))
    live_ms = instant.stage_ms()["compensate"][0]
    print(
        f"  network alone as 'edofproj bench' times it: {bench_ms:.2f} ms median; in the loop {live_ms:.2f} ms "
        f"({100 * (live_ms / bench_ms - 1):+.0f} %)"
    )

    # 2. the virtual ProCams: every capture simulated
    display = MemoryDisplay()
    camera = VirtualCamera(rig, display)
    run_live(net, calibration, display, camera, [("warm-up", target)])
    virtual = run_live(net, calibration, display, camera, [("target", target)] * args.virtual_frames, measure=False)
    print_summary("virtual ProCams (simulated capture)", virtual)
    capture_ms = virtual.stage_ms()["capture"][0]
    print(
        f"  target 1 / (capture + 10 ms) = {1e3 / (capture_ms + 10):.2f} frames/s; measured {virtual.fps:.2f} frames/s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
