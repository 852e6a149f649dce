"""``edofproj compensate``: the trained network on image files -> the image to send to the projector.

    edofproj compensate RUN --image TARGET --capture CAPTURED --out PROJ.png
    edofproj compensate RUN --image TARGET --depth-mm Z --out PROJ.png [--preview SHOWN.png]
    edofproj compensate RUN --image TARGET --capture RAW --calib calib.npz --out PROJ.png

The network computes ``x = net(I, I*)`` from the desired image ``I`` and the uncompensated
projection ``I*``: either a camera capture already warped into projector space (``--capture``,
same size as the target) or the simulated capture ``I* = project(I, p_z)`` of the run's DOE on a
flat screen at ``--depth-mm``. ``x`` is clamped to ``[0, 1]`` (what a projector can emit) and
written as an 8- or 16-bit image. Any image size. With ``--depth-mm``, ``--preview`` also writes
the simulated projection of ``x``, and the command prints the SSIM and PSNR against the target of
that projection and of the uncompensated projection ``I*`` (what the network gains there).

With ``--calib`` (from ``edofproj procams calibrate``) the capture is a *raw* camera frame: it is
rectified into projector output light per projector pixel, and the output is the projector
*input* ``u = f^-1(x)`` that emits the light ``x`` (the inverse of the measured response).
The target is then projector output light (full primary = 1); see docs/procams.md.
"""

from __future__ import annotations

import math

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, run_directory


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compensate",
        help="compute the projector image for a target with a trained network",
        description=__doc__.split("\n")[0],
    )
    p.add_argument("run", metavar="RUN", type=run_directory, help="trained run directory" + RUN_HELP_SUFFIX)
    p.add_argument("--image", required=True, metavar="TARGET", help="the desired image (PNG/JPEG/TIFF)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--capture",
        default=None,
        metavar="CAPTURED",
        help="the uncompensated projection captured by a camera, warped to projector space",
    )
    source.add_argument(
        "--depth-mm",
        type=float,
        default=None,
        help="simulate the capture on a flat screen at this depth (mm) with the run's DOE",
    )
    p.add_argument(
        "--calib",
        default=None,
        metavar="calib.npz",
        help="with --capture: the capture is a raw camera frame; rectify it and invert the projector's response",
    )
    p.add_argument("--out", required=True, metavar="PROJ", help="output image: the projector input")
    p.add_argument(
        "--preview",
        default=None,
        metavar="SHOWN",
        help="with --depth-mm: also write the simulated projection of the output",
    )
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="bits per channel of the outputs")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch

    from ..compensation.closed_loop import closed_loop, flat_screen
    from ..evaluation.pipeline import require_trained_run
    from ..imaging.image_io import check_output_path, read_image, write_image
    from ..runs import load_run

    if args.calib is not None and args.capture is None:
        raise EdofprojError("--calib goes with --capture (a raw camera frame to rectify)")
    if args.preview is not None and args.depth_mm is None:
        raise EdofprojError("--preview needs --depth-mm (a simulated screen to show the result on)")
    if args.depth_mm is not None and not (math.isfinite(args.depth_mm) and args.depth_mm > 0):
        raise EdofprojError(f"--depth-mm must be a positive depth in mm, got {args.depth_mm:g}")
    check_output_path(args.out, args.bits)
    if args.preview is not None:
        check_output_path(args.preview, args.bits)
    trained = load_run(require_trained_run(args.run))
    target = read_image(args.image).unsqueeze(0)
    psf = None
    calibration = None
    if args.calib is not None:
        from ..procams.calibration import ProCamsCalibration
        from ..procams.capture_io import read_rgb

        calibration = ProCamsCalibration.load(args.calib)
        calibration.check_projector_hw((target.shape[-2], target.shape[-1]), what=f"--image '{args.image}'")
        light = calibration.to_output_space(read_rgb(args.capture, what="capture"))
        captured = torch.from_numpy(light.astype("float32").transpose(2, 0, 1).copy())[None]
    elif args.capture is not None:
        captured = read_image(args.capture).unsqueeze(0)
        if captured.shape != target.shape:
            raise EdofprojError(
                f"--image is {target.shape[-2]}x{target.shape[-1]} px but --capture is "
                f"{captured.shape[-2]}x{captured.shape[-1]} px (height x width): warp the capture to projector space"
            )
    else:
        from ..evaluation.designs import OpticalDesign

        psf = OpticalDesign("run", "doe", trained.doe, trained.cfg).psf([args.depth_mm * 1e-3])
    with torch.inference_mode():
        # a simulated screen runs the whole loop (its projection is the preview); a capture, the network alone
        loop = closed_loop(target, flat_screen(psf), trained.net) if psf is not None else None
        emitted = loop.emitted if loop is not None else trained.net(target, captured).clamp(0.0, 1.0)
    if calibration is not None:
        write_image(args.out, calibration.to_projector_input(emitted)[0], bits=args.bits)
        print(
            f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px): projector input (measured response inverted)"
        )
        return 0
    write_image(args.out, emitted[0], bits=args.bits)
    print(f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px, height x width)")
    if args.preview is not None:
        if loop is None:  # refused above: --preview needs --depth-mm, which excludes --capture
            raise EdofprojError("--preview needs --depth-mm (a simulated screen to show the result on)")
        write_image(args.preview, loop.projected[0], bits=args.bits)
        print(f"wrote {args.preview}: simulated projection at {args.depth_mm:g} mm")
    if loop is not None:
        print(
            f"against the target at {args.depth_mm:g} mm: compensated (the preview) {_quality(loop.projected, target)}; "
            f"uncompensated projection {_quality(loop.captured, target)}"
        )
    return 0


def _quality(shown, target) -> str:
    """``SSIM s, PSNR p dB`` of a simulated projection against the target (PSNR alone below SSIM's window)."""
    from ..metrics import gaussian_window, psnr, ssim

    text = f"PSNR {float(psnr(shown, target)[0]):.2f} dB"
    if min(target.shape[-2:]) >= gaussian_window().numel():
        text = f"SSIM {float(ssim(shown, target)[0]):.4f}, " + text
    return text
