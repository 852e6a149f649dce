"""``edofproj live``: live compensation on a projector with a camera in the loop.

    edofproj live RUN --calib calib.npz --camera SPEC --display SPEC (--image F | --images DIR | --video F)

For each frame: show the target ``I``, capture ``I*``, rectify it into projector space,
compensate with the run's method (``--method``, default the run's own network behind its display
guard where it has one, built exactly as ``edofproj evaluate`` scores it; a blind method: the loop
does not know the screen's depth), show ``Î`` (through the inverse of the measured projector
response). Display, camera and network run in their own threads, so a frame is captured while
the previous one is computed. Prints each frame, then the throughput (frames/s), the latency
(target taken -> compensated frame shown; median and 99th percentile) and each stage's median
and 99th percentile. A camera that returns no frame for ``--stall-timeout-s`` is reported in one
line while the last compensated frame stays on screen. ``--frames N`` stops after N frames;
Ctrl-C or SIGTERM stops cleanly ("interrupted", the summary of the frames done, exit code 0).
``--camera virtual:CAPTURES --display memory`` runs it headless through the virtual ProCams of a
'procams simulate' folder. ``--device cuda`` rectifies, compensates and inverts the response on the
GPU (the camera frame goes there, the projector input comes back); the default runs them on the CPU.

On a coloured, textured object whose surface the calibration holds (``procams calibrate
--surface-captures``), a run trained with ``net.surface_input`` compensates for it (a calibration
without the surface is then refused in one line), and any other network does with
``--surface-from-calib`` (after the photometric correction): the target shown first is then the
photometric correction of the goal, the target scaled into what the surface can show
(:class:`edofproj.application.surface_frames.SurfaceLoop`; docs/procams.md). Without either, a
surface in the calibration is not used (a note says so).
"""

from __future__ import annotations

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, add_device_option, add_method_options, run_directory

DEFAULT_STALL_TIMEOUT_S = 2.0  # application.live.DEFAULT_STALL_TIMEOUT_S, not imported: --help stays fast


def register(subparsers) -> None:
    from .procams.devices import add_device_options

    p = subparsers.add_parser(
        "live", help="live compensation: show, capture, rectify, compensate, show", description=__doc__.split("\n")[0]
    )
    p.add_argument(
        "run", metavar="RUN", type=run_directory, help="trained (or fine-tuned) run directory" + RUN_HELP_SUFFIX
    )
    add_method_options(p, blind_only=True)
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    add_device_options(p)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--image", default=None, help="one target image, shown again every frame")
    source.add_argument("--images", default=None, metavar="DIR", help="a folder of target images, in turn")
    source.add_argument("--video", default=None, help="a video file, frame by frame")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames (default: Ctrl-C)")
    p.add_argument(
        "--stall-timeout-s",
        type=float,
        default=DEFAULT_STALL_TIMEOUT_S,
        help=f"report a camera that returns no frame for this long, s ({DEFAULT_STALL_TIMEOUT_S:g})",
    )
    p.add_argument(
        "--measure",
        action="store_true",
        help="also capture each compensated projection and print SSIM of both captures against the target "
        "(on a surface: against the goal)",
    )
    add_device_option(p, "rectify, compensate and turn each frame into projector input (not on a surface)")
    p.add_argument(
        "--surface-from-calib",
        action="store_true",
        help="compensate for the surface measured in the calibration, after its photometric correction "
        "(implied for a run trained with net.surface_input)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    import numpy as np
    import torch

    from ..application.live import frame_source, run_live
    from ..application.surface_frames import SurfaceLoop
    from ..compensation.surface_net import SurfaceAwareNet
    from ..methods.builder import build_method
    from ..procams.calibration import ProCamsCalibration
    from ..training.distributed import choose_device
    from .procams.devices import open_devices

    if args.frames is not None and args.frames < 1:
        raise EdofprojError(f"--frames {args.frames} must be >= 1")
    method = build_method(args.run, args.method, args.baselines)
    if not method.blind:
        raise EdofprojError(
            f"--method {method.name} is not blind: it needs the screen's PSF, which the live loop does not know"
        )
    device = choose_device(args.device, option="--device")
    calibration = ProCamsCalibration.load(args.calib)
    surface = None
    # a surface-aware network is given the surface (doe+surface-net); any other method runs after the
    # photometric correction (M+photometric), as evaluate --surface scores them
    surface_aware = isinstance(method.network, SurfaceAwareNet)
    net = method.network.eval() if surface_aware and method.network is not None else method.frame_function()
    if args.surface_from_calib or surface_aware:
        what = (
            "--surface-from-calib" if args.surface_from_calib else "the run's surface-aware network (net.surface_input)"
        )
        if device.type != "cpu":
            raise EdofprojError(
                f"the live loop on a surface ({what}) runs on the CPU: leave out --device {args.device}"
            )
        surface = SurfaceLoop(calibration, net, what)
    elif calibration.has_surface:
        print(
            f"note: the surface measured in {args.calib} is not used (--surface-from-calib compensates for it)",
            file=sys.stderr,
        )
    if isinstance(net, torch.nn.Module):
        net = net.to(device)
    targets = frame_source(calibration.projector_hw, image=args.image, images=args.images, video=args.video)
    display, camera, grab = open_devices(args)

    def report(frame) -> None:
        line = f"frame {frame.name}: latency {1e3 * frame.latency_s:.0f} ms"
        if frame.ssim_compensated is not None:
            line += f", SSIM uncompensated {frame.ssim_uncompensated:.4f} -> compensated {frame.ssim_compensated:.4f}"
        print(line)

    with display, camera:
        H, W = calibration.projector_hw
        print(
            f"live: {H}x{W} (height x width) projector, method {method.name}, camera '{camera.spec}', display '{display.spec}', "
            f"on {device}"
            + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else "")
            + " (Ctrl-C stops)"
        )
        summary = run_live(
            net,
            calibration,
            display,
            camera,
            targets,
            grab,
            frames=args.frames,
            measure=args.measure,
            on_frame=report,
            stall_timeout_s=args.stall_timeout_s,
            report=lambda line: print(f"live: {line}", flush=True),
            surface=surface,
            device=device if device.type != "cpu" else None,
        )
    if summary.interrupted:
        print("interrupted")
    if not summary.frames:
        print("no frame completed")
        return 0
    latency_median, latency_p99 = summary.latency_ms()
    print(
        f"{summary.frames} frames, throughput {summary.fps:.2f} frames/s, latency median {latency_median:.0f} ms "
        f"(99th percentile {latency_p99:.0f} ms)" + (f", camera stalls {summary.stalls}" if summary.stalls else "")
    )
    stats = summary.stage_ms()
    print(
        "ms per stage, median / 99th percentile: " + ", ".join(f"{s} {m:.1f} / {p:.1f}" for s, (m, p) in stats.items())
    )
    if summary.ssim_compensated:
        print(
            f"mean SSIM against the {'goals' if surface is not None else 'targets'}: "
            f"uncompensated {np.mean(summary.ssim_uncompensated):.4f}, "
            f"compensated {np.mean(summary.ssim_compensated):.4f}"
        )
    return 0
