"""``edofproj procams calibrate``: geometric and colour calibration from captured patterns.

    edofproj procams calibrate --patterns PATTERNS --captures CAPTURES --out calib.npz

The dot grid gives the map from camera to projector pixels (a homography and the lens distortion
beyond it), the colour samples the projector's colour response as the camera sees it.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError


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
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.calibration import calibrate_folders

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    manifest, calibration = calibrate_folders(args.patterns, args.captures, neighbours=args.neighbours)
    calibration.save(args.out)
    cm = calibration.camera_map
    print(
        f"wrote {args.out}: {len(cm.dots_proj)} dots matched, camera {cm.camera_hw[1]}x{cm.camera_hw[0]}, "
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
    return 0
