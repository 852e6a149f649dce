"""The pipelined live loop at 600x800: stage times, throughput and latency, in two set-ups.

The loop of ``edofproj live`` (:func:`edofproj.application.live.run_live`): show the target
through the inverse projector response, capture it, rectify it into projector space, compensate
with the network, invert the response, show the result -- display, camera and compute in their
own threads. The network is the method ``edofproj live`` ships for ``--run`` (its network behind
its display guard where the run has one), or an untrained network of ``--config`` (the
``realtime`` preset; its cost does not depend on its weights). The rig is
``VirtualProCams.example`` at the projector size (camera ``--camera-scale`` px per projector px,
``--supersampling`` sub-samples per camera pixel, lens PSF at ``--depth-mm``), calibrated
ideally (:meth:`VirtualProCams.ideal_calibration`; the loop's cost does not depend on how the
calibration was measured).

0. **each stage alone**: the per-call computations the loop made before it had tables, and the
   tables, one after the other in one thread (medians of wall time and thread CPU time).
1. **instant camera**: an in-memory display and a camera that returns a ready frame (one
   virtual capture of the target, made before timing): what the loop costs around the network.
   Targets: >= 30 frames/s; the ``compensate`` stage (the network alone) within 20 % of the
   network's time as ``edofproj bench`` measures it (same process, same threads, printed).
2. **virtual ProCams**: the camera simulates the optics and the sensor for every frame (on a real
   rig that is the camera's frame time). Target: frames/s >= 1 / (capture + 10 ms).

Each prints a table: stage, median ms, 99th percentile ms, and the median CPU time of the thread
that ran the stage (what the stage costs, without the time its thread waited for a core: on a
loaded machine wall times are far above it); throughput; latency (target taken -> compensated
frame on screen, median and 99th percentile); and the throughput the three threads' CPU times
allow with a core each. PyTorch and OpenCV run one thread each (``--threads``), so that each
stage's work stays in the thread that times it.

With ``--device cuda`` part 1 runs twice: first with the network alone on the GPU inside the CPU
loop (``compensate`` then includes copying the two images to the GPU and the result back), then as
``edofproj live --device cuda`` runs it, with the frame maps on the GPU too
(:class:`edofproj.procams.device_frame_maps.DeviceFrameMaps`: the camera frame goes to the GPU in
its 8-bit counts, is rectified, compensated and turned into projector input there, and only the
projector input comes back; each stage waits for the GPU at its end). The network alone is timed
on the GPU as ``edofproj bench --device cuda`` times it.

    PYTHONPATH=src python benchmarks/bench_live.py [--size 600x800] [--frames 60] [--virtual-frames 8] [--device cuda]
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np
import torch

from edofproj.application.live import STAGES, LiveSummary, run_live
from edofproj.compensation.registry import build_network
from edofproj.config import load_config
from edofproj.data import build_test_images
from edofproj.doe import build_doe
from edofproj.evaluation.timing import measure_ms, network_torch_case
from edofproj.machine import instruction_sets
from edofproj.methods.builder import build_method
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.procams.devices.base import Camera
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.frame_maps import TrilinearInverseTable
from edofproj.procams.virtual import VirtualProCams

OUTSIDE_NETWORK = ("rectify", "to_input")
"""The per-frame work of the compute thread besides the network (the display's and camera's own
time runs in their threads and is listed separately)."""


class InstantCamera(Camera):
    """Returns the same ready frame at once: a camera that costs nothing (``grab_native``: the
    sensor's counts as the loop takes them; ``grab``: the same frame in float32)."""

    spec = "instant"

    def __init__(self, frame: np.ndarray) -> None:
        self.frame = frame

    def grab(self) -> np.ndarray:
        return self.frame.astype(np.float32) / np.float32(np.iinfo(self.frame.dtype).max)

    def grab_native(self) -> np.ndarray:
        return self.frame


class NetworkOnDevice(torch.nn.Module):
    """``net`` on ``device`` behind the loop's CPU tensors: ``net(I, I*)`` with both images copied to
    the device and the compensated image copied back ((1, 3, H, W) in and out)."""

    def __init__(self, net: torch.nn.Module, device: torch.device) -> None:
        super().__init__()
        self.net, self.device = net.to(device), device
        self.channels_last_inputs = getattr(net, "channels_last_inputs", True)

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        on_device = self.net(target.to(self.device, non_blocking=True), captured.to(self.device, non_blocking=True))
        return on_device.cpu()


def load_line() -> str:
    """The machine's load average (1, 5, 15 min) and its cores: the context of every wall time."""
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} on {os.cpu_count()} cores [{instruction_sets()}]"


def print_summary(title: str, summary: LiveSummary) -> None:
    print(f"\n{title}: {summary.frames} frames ({load_line()})")
    print(f"  {'stage':<17} {'median ms':>10} {'p99 ms':>8} {'CPU ms':>8}")
    stats, cpu = summary.stage_ms(), summary.stage_cpu_ms()
    for stage in STAGES + ("check",):
        if stage in stats:
            print(f"  {stage:<17} {stats[stage][0]:10.2f} {stats[stage][1]:8.2f} {cpu[stage]:8.2f}")
    outside, outside_cpu = sum(stats[s][0] for s in OUTSIDE_NETWORK), sum(cpu[s] for s in OUTSIDE_NETWORK)
    print(f"  outside the network (rectify + to_input): {outside:.2f} ms per frame, CPU {outside_cpu:.2f} ms (medians)")
    median, p99 = summary.latency_ms()
    print(f"  throughput {summary.fps:.1f} frames/s; latency median {median:.1f} ms, p99 {p99:.1f} ms")
    print(f"  throughput the threads' CPU times allow, a core each: {summary.cpu_limited_fps():.1f} frames/s")
    if summary.stalls:
        print(f"  camera stalls: {summary.stalls}")


def cpu_ms(function, repeats: int) -> tuple[float, float]:
    """Median wall-clock ms and mean thread-CPU ms of ``function()`` (after one warm-up call)."""
    function()
    walls = []
    cpu_start = time.thread_time()
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        walls.append(time.perf_counter() - start)
    return 1e3 * float(np.median(walls)), 1e3 * (time.thread_time() - cpu_start) / repeats


def print_stages_alone(calibration, frame_counts: np.ndarray, target: np.ndarray, repeats: int) -> None:
    """Each per-frame stage alone, one after the other in this thread: as computed per call before
    the loop had tables (``to_output_space``: warp of the float frame with float64 maps converted per
    call, float64 unmixing; the 65^3 ``ResponseLUT`` read by ``grid_sample`` for the target and the
    output) and with the tables (:mod:`edofproj.procams.frame_maps`), the camera frame as float32 in
    ``[0, 1]`` and as the sensor's 8-bit counts; the 3-D table a non-separable response would use."""
    H, W = calibration.projector_hw
    frame = frame_counts.astype(np.float32) / np.float32(255.0)
    light_chw = torch.from_numpy(target.transpose(2, 0, 1).copy())[None]
    light_hwc = torch.from_numpy(target)  # the layout of the network's channels_last output
    lut = calibration.color.inverse_response_lut(calibration.response_lut_size)
    trilinear = TrilinearInverseTable(lut.table)
    out = np.empty((H, W, 3), np.float32)
    out_t = torch.from_numpy(out)
    cases = [
        ("rectify", "before", lambda: calibration.to_output_space(frame)),
        ("rectify, float32 frame", "after", lambda: calibration.rectifier(frame, out=out)),
        ("rectify, uint8 frame", "after", lambda: calibration.rectifier(frame_counts, out=out)),
        ("to_input", "before", lambda: lut(light_chw)[0].numpy().transpose(1, 2, 0).copy()),
        ("to_input, per-channel", "after", lambda: calibration.inverse_table.apply(light_hwc, out=out_t)),
        ("to_input, 3-D trilinear", "after", lambda: trilinear.apply(light_hwc, out=out_t)),
        ("show_target f^-1(I)", "before", lambda: lut(light_chw)[0].numpy().transpose(1, 2, 0).copy()),
    ]
    print(f"\neach stage alone ({repeats} calls each; after: the tables the loop builds once; {load_line()})")
    print(f"  {'stage':<26} {'':<7} {'median ms':>10} {'CPU ms':>8}")
    for stage, when, function in cases:
        wall, cpu = cpu_ms(function, repeats)
        print(f"  {stage:<26} {when:<7} {wall:10.2f} {cpu:8.2f}")
    print(f"  {'show_target f^-1(I)':<26} {'after':<7} {'cached per target: 0':>19}")


def virtual_rig(
    cfg,
    height: int,
    width: int,
    depth_mm: float = 400.0,
    window: int = 21,
    camera_scale: float = 1.5,
    supersampling: int = 2,
):
    """``(rig, calibration, target)``: ``VirtualProCams.example`` at the projector size ``height x width``
    with the lens PSF of ``cfg`` at ``depth_mm``, its ideal calibration (tables built) and the first test
    image of ``cfg.data`` as an ``(H, W, 3)`` float array (module docstring)."""
    psf = simulator_from_config(cfg, window=window).bank(build_doe(cfg, "lens"), [depth_mm * 1e-3]).psf
    rig = VirtualProCams.example(
        (height, width), psf[0].double().numpy(), camera_scale=camera_scale, supersampling=supersampling
    )
    calibration = rig.ideal_calibration()
    _ = calibration.rectifier, calibration.inverse_table
    target = build_test_images(cfg.data, size=(height, width))[0][1].numpy().transpose(1, 2, 0).copy()
    return rig, calibration, target


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
    parser.add_argument("--threads", type=int, default=1, help="PyTorch and OpenCV threads (1)")
    parser.add_argument("--device", default="cpu", help="where the network runs: cpu or cuda (cpu)")
    parser.add_argument("--skip-virtual", action="store_true", help="skip part 2 (the simulated captures)")
    args = parser.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: PyTorch sees no CUDA GPU here")
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    height, width = (int(v) for v in args.size.lower().split("x"))
    if args.run:  # what `edofproj live RUN` runs: the shipped method's module
        method = build_method(args.run)
        if method.module is None:
            parser.error(f"--run {args.run}: its method {method.name} has no network")
        cfg, net = method.design.cfg, method.module.eval()
    else:
        cfg = load_config(args.config)
        net = build_network(cfg.net).eval()
    module = net  # what runs on the GPU, without the wrapper that copies its images there and back
    if device.type != "cpu":
        net = NetworkOnDevice(net, device)
    start = time.perf_counter()
    rig, calibration, target = virtual_rig(
        cfg, height, width, args.depth_mm, args.window, args.camera_scale, args.supersampling
    )
    setup_s = time.perf_counter() - start
    print(
        f"live loop, {width}x{height} projector, camera {rig.camera_hw[1]}x{rig.camera_hw[0]} "
        f"(x{args.supersampling} sub-samples), {torch.get_num_threads()} PyTorch thread(s), network "
        f"'{args.run or args.config}'; rig, calibration tables and target built in {setup_s:.2f} s "
        f"(inverse response: {type(calibration.inverse_table).__name__}); network on {device}"
        + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else "")
    )

    # 0. each stage alone: the per-call computations the loop used before against its tables
    display = MemoryDisplay()
    display.show(calibration.inverse_table.apply(torch.from_numpy(target)).numpy())
    frame = VirtualCamera(rig, display).grab_native()  # the sensor's 8-bit counts
    print_stages_alone(calibration, frame, target, args.frames)

    # 1. instant camera: one virtual capture of the target, returned at once
    camera: Camera = InstantCamera(frame)
    run_live(net, calibration, MemoryDisplay(), camera, [("warm-up", target)] * 3)
    instant = run_live(net, calibration, MemoryDisplay(), camera, [("target", target)] * args.frames)
    print_summary(
        "instant camera, in-memory display" + (", the network alone on the GPU" if device.type != "cpu" else ""),
        instant,
    )
    if device.type != "cpu":  # as `edofproj live --device cuda`: every per-frame stage on the GPU
        run_live(module, calibration, MemoryDisplay(), camera, [("warm-up", target)] * 3, device=device)
        on_device = run_live(
            module, calibration, MemoryDisplay(), camera, [("target", target)] * args.frames, device=device
        )
        print_summary("instant camera, in-memory display, rectify + compensate + to_input on the GPU", on_device)
    bench_frame = network_torch_case(module, "net", device=str(device)).build(height, width)
    sync = torch.cuda.synchronize if device.type == "cuda" else None
    if sync is not None:  # the first calls on a GPU pick kernels
        measure_ms(bench_frame, repeats=1, warmup=3, synchronize=sync)
    cpu_start = time.thread_time()
    repeats = max(10, args.frames // 2)
    bench_ms = float(np.median(measure_ms(bench_frame, repeats=repeats, warmup=0, synchronize=sync)))
    bench_cpu_ms = 1e3 * (time.thread_time() - cpu_start) / repeats
    live_ms, live_cpu_ms = instant.stage_ms()["compensate"][0], instant.stage_cpu_ms()["compensate"]
    print(
        f"  network alone as 'edofproj bench' times it: {bench_ms:.2f} ms median (CPU {bench_cpu_ms:.2f} ms mean); "
        f"in the loop {live_ms:.2f} ms ({100 * (live_ms / bench_ms - 1):+.0f} %), CPU {live_cpu_ms:.2f} ms "
        f"({100 * (live_cpu_ms / bench_cpu_ms - 1):+.0f} %)"
    )

    # 2. the virtual ProCams: every capture simulated
    if args.skip_virtual:
        return 0
    display = MemoryDisplay()
    camera = VirtualCamera(rig, display)
    run_live(net, calibration, display, camera, [("warm-up", target)])
    virtual = run_live(net, calibration, display, camera, [("target", target)] * args.virtual_frames, measure=False)
    print_summary("virtual ProCams (simulated capture)", virtual)
    capture_ms = virtual.stage_ms()["capture"][0]
    print(
        f"  target 1 / (capture + 10 ms) = {1e3 / (capture_ms + 10):.2f} frames/s (capture median {capture_ms:.0f} ms); "
        f"measured {virtual.fps:.2f} frames/s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
