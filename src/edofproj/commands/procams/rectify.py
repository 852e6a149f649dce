"""``edofproj procams rectify``: raw camera captures to projector output light per projector pixel.

    edofproj procams rectify CAPTURE --calib calib.npz --out OUT

One capture or a folder of them, through the calibration's geometric map and colour response.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over


def register(subparsers) -> None:
    """Add ``procams rectify`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("rectify", help="raw camera captures -> projector output light per projector pixel")
    p.add_argument("capture", metavar="CAPTURE", help="a raw capture (image file) or a folder of them")
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    p.add_argument("--out", required=True, help="output image (for one capture) or folder (for a folder)")
    p.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per channel of the output PNGs (16)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...imaging.image_io import IMAGE_EXTENSIONS, check_output_path, write_image
    from ...outputs import refuse_colliding_names
    from ...procams.calibration import ProCamsCalibration
    from ...procams.capture_io import atomic_folder, read_rgb

    inputs = [("CAPTURE", args.capture), ("--calib", args.calib)]
    refuse_output_over(args.out, "--out", inputs, file_output=not Path(args.capture).is_dir())
    source = Path(args.capture)
    files = []
    if source.is_dir():  # the folder's files and their output names, checked before any work
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
        if not files:
            raise EdofprojError(f"capture folder '{source}' holds no image")
        refuse_colliding_names(files, lambda path: path.stem + ".png", what=f"the captures of '{source}'")
    calibration = ProCamsCalibration.load(args.calib)

    def rectified(path: Path) -> np.ndarray:
        light = calibration.to_output_space(read_rgb(path, what="capture"))
        return np.ascontiguousarray(light.transpose(2, 0, 1))

    if source.is_dir():
        with atomic_folder(args.out, what="edofproj procams rectify") as tmp:
            for path in files:
                write_image(tmp / (path.stem + ".png"), rectified(path), bits=args.bits)
        print(f"wrote {len(files)} rectified captures to {args.out}")
    else:
        check_output_path(args.out, args.bits)
        write_image(args.out, rectified(source), bits=args.bits)
        print(f"wrote {args.out}")
    H, W = calibration.projector_hw
    print(
        f"projector space: {H}x{W} (height x width), projector output light (full primary = 1; clipped to [0, 1] in the file)"
    )
    return 0
