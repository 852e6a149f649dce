"""``edofproj live``: live compensation on a projector with a camera in the loop.

    edofproj live RUN --calib calib.npz --camera SPEC --display SPEC (--image F | --images DIR | --video F)

For each frame: show the target ``I``, capture ``I*``, rectify it into projector space,
compensate with the run's network, show ``Î`` (through the inverse of the measured projector
response). Prints frames per second and the latency of each stage; ``--frames N`` stops
after N frames, Ctrl-C stops cleanly. ``--camera virtual:CAPTURES --display memory`` runs it
headless through the virtual ProCams of a 'procams simulate' folder.
"""

from __future__ import annotations

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, run_directory


def register(subparsers) -> None:
    from .procams import add_device_options

    p = subparsers.add_parser(
        "live", help="live compensation: show, capture, rectify, compensate, show", description=__doc__.split("\n")[0]
    )
    p.add_argument(
        "run", metavar="RUN", type=run_directory, help="trained (or fine-tuned) run directory" + RUN_HELP_SUFFIX
    )
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    add_device_options(p)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--image", default=None, help="one target image, shown again every frame")
    source.add_argument("--images", default=None, metavar="DIR", help="a folder of target images, in turn")
    source.add_argument("--video", default=None, help="a video file, frame by frame")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames (default: Ctrl-C)")
    p.add_argument(
        "--measure",
        action="store_true",
        help="also capture each compensated projection and print SSIM of both captures against the target",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..application.live import STAGES, frame_source, run_live
    from ..evaluation.pipeline import require_trained_run
    from ..procams.calibration import ProCamsCalibration
    from ..runs import load_run
    from .procams import open_devices

    if args.frames is not None and args.frames < 1:
        raise EdofprojError(f"--frames {args.frames} must be >= 1")
    trained = load_run(require_trained_run(args.run))
    calibration = ProCamsCalibration.load(args.calib)
    targets = frame_source(calibration.projector_hw, image=args.image, images=args.images, video=args.video)
    display, camera, grab = open_devices(args)

    def report(frame) -> None:
        line = f"frame {frame.name}: {1e3 * sum(frame.stage_s[s] for s in STAGES):.0f} ms"
        if frame.ssim_compensated is not None:
            line += f", SSIM uncompensated {frame.ssim_uncompensated:.4f} -> compensated {frame.ssim_compensated:.4f}"
        print(line)

    with display, camera:
        H, W = calibration.projector_hw
        print(f"live: {W}x{H} projector, camera '{camera.spec}', display '{display.spec}' (Ctrl-C stops)")
        summary = run_live(
            trained.net,
            calibration,
            display,
            camera,
            targets,
            grab,
            frames=args.frames,
            measure=args.measure,
            on_frame=report,
        )
    if summary.interrupted:
        print("interrupted")
    if not summary.frames:
        print("no frame completed")
        return 0
    stages = ", ".join(f"{stage} {ms:.1f}" for stage, ms in summary.mean_stage_ms().items())
    print(f"{summary.frames} frames, {summary.fps:.2f} frames/s; mean ms per stage: {stages}")
    if summary.ssim_compensated:
        print(
            f"mean SSIM against the targets: uncompensated {np.mean(summary.ssim_uncompensated):.4f}, "
            f"compensated {np.mean(summary.ssim_compensated):.4f}"
        )
    return 0
