"""``edofproj procams calibrate``: geometric and colour calibration from captured patterns.

    edofproj procams calibrate --patterns PATTERNS --captures CAPTURES --out calib.npz
                               [--surface-captures OBJECT_CAPTURES]

The dot grid gives the map from camera to projector pixels (a homography and the lens distortion
beyond it), the colour samples the projector's colour response as the camera sees it.

With ``--surface-captures`` (a capture folder of the same patterns taken with the coloured,
textured object in place; only its ``black.png`` and ``white.png`` are read) the surface's
reflectance and ambient per projector pixel are measured too (:mod:`edofproj.procams.surface`)
and kept in the calibration file (keys ``surface_reflectance``, ``surface_ambient``), for
``compensate --calib``. ``--captures`` must then be of a white screen (or white board) where the
object stands: its colour calibration defines white.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over


def register(subparsers) -> None:
    """Add ``procams calibrate`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("calibrate", help="geometric and colour calibration from captured patterns")
    p.add_argument("--patterns", required=True, help="pattern folder")
    p.add_argument("--captures", required=True, help="capture folder (one capture per pattern, same names)")
    p.add_argument("--out", required=True, help="output calibration .npz")
    p.add_argument(
        "--neighbours",
        type=int,
        default=6,
        metavar="K",
        help="nearest colour samples in the local linear response interpolation (6)",
    )
    p.add_argument(
        "--surface-captures",
        default=None,
        metavar="DIR",
        help="capture folder of the same patterns with the textured object in place: measure its reflectance and "
        "ambient (its black and white fields) into the calibration",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.calibration import calibrate_folders

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    inputs = [
        ("--patterns", args.patterns),
        ("--captures", args.captures),
        ("--surface-captures", args.surface_captures),
    ]
    refuse_output_over(args.out, "--out", inputs, file_output=True)
    manifest, calibration = calibrate_folders(args.patterns, args.captures, neighbours=args.neighbours)
    if args.surface_captures is not None:
        from ...procams.surface import measure_surface_folders

        measured = measure_surface_folders(calibration, args.patterns, args.surface_captures, args.captures)
        calibration = calibration.with_surface(measured.reflectance, measured.ambient)
    calibration.save(args.out)
    cm = calibration.camera_map
    print(
        f"wrote {args.out}: {len(cm.dots_proj)} dots matched, camera {cm.camera_hw[0]}x{cm.camera_hw[1]} (height x width), "
        f"{cm.camera_pixels_per_projector_pixel():.2f} camera px per projector px, lens distortion up to "
        f"{cm.homography_residual_px().max():.2f} camera px beyond the homography"
    )
    print("colour-mixing matrix (camera RGB per unit projector output):")
    for row in calibration.color.mixing_matrix:
        print("  " + " ".join(f"{v:8.4f}" for v in row))
    print(
        f"{len(calibration.color.sample_inputs)} colour samples, black level "
        f"{np.round(calibration.color.black_level, 4).tolist()}"
    )
    if calibration.has_surface:
        rho, ambient = calibration.require_surface()
        rho_median = ", ".join(f"{v:.3f}" for v in np.median(rho, axis=(0, 1)))
        ambient_median = ", ".join(f"{v:.4f}" for v in np.median(ambient, axis=(0, 1)))
        print(
            f"surface from {args.surface_captures}: reflectance median RGB ({rho_median}), 2-98 % "
            f"{np.percentile(rho, 2):.3f}-{np.percentile(rho, 98):.3f}; ambient median RGB ({ambient_median}) "
            "(projector output units)"
        )
    return 0
