"""``edofproj procams predict``: predict the capture of a projector image and score it against the real one.

    edofproj procams predict --map map.npz [--psf-map psf_map.npz] --image PROJ.png --capture CAP.png
                             [--black BLACK.png --white WHITE.png] [--out PRED.png]

The projector image (grey: the mean of its channels) blurred by the PSF map, seen through the map,
scaled between the per-pixel dark and bright levels (the black and white captures, or the map's), with the capture's own gain and offset
fitted (auto-exposure); PSNR and SSIM over the valid region (:mod:`edofproj.procams.prediction`).
Without ``--psf-map``: the same model without blur, registered at ``--offset-px`` (default 0 0);
``--psf-map P --no-blur``: without blur at the registration the blurred prediction has (P's offset),
so that the two scores differ by the blur alone. This is how a lab checks its model before it
trusts compensation.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over


def register(subparsers) -> None:
    """Add ``procams predict`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("predict", help="predict a projector image's capture and score it (PSNR, SSIM)")
    p.add_argument("--map", required=True, help="camera->projector map of the capture's camera pose ('procams decode')")
    p.add_argument("--psf-map", default=None, help="PSF map ('procams psf-map'); without it: no blur")
    p.add_argument("--image", required=True, help="the projector image (at the projector's size)")
    p.add_argument("--capture", required=True, help="its capture")
    p.add_argument("--black", default=None, help="a capture of the black field (dark level; default: the map's)")
    p.add_argument("--white", default=None, help="a capture of the white field (bright level; default: the map's)")
    p.add_argument(
        "--channel",
        default="mean",
        choices=("mean", "red", "green", "blue"),
        help="grey from (mean); a per-colour PSF map's map of that colour",
    )
    p.add_argument(
        "--offset-px",
        type=float,
        nargs=2,
        default=None,
        metavar=("X", "Y"),
        help="the map's offset o (default: the PSF map's estimate; 0 0 for a map anchored to a Gray code)",
    )
    p.add_argument(
        "--no-blur",
        action="store_true",
        help="with --psf-map: register with the PSF map's offset but do not blur (the same registration as with blur)",
    )
    p.add_argument("--out", default=None, help="write the predicted capture (8-bit PNG, black outside the region)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...fileio import read_arrays
    from ...procams.capture_io import read_rgb, write_rgb_png
    from ...procams.lab_manifest import to_grey
    from ...procams.prediction import predict_capture
    from ...procams.psf_map import load_psf_maps
    from ...procams.structured_light import CorrespondenceMap

    inputs = [("--map", args.map), ("--psf-map", args.psf_map), ("--image", args.image), ("--capture", args.capture)]
    inputs += [("--black", args.black), ("--white", args.white)]
    refuse_output_over(args.out, "--out", inputs, file_output=True)

    corr = CorrespondenceMap.load(args.map)
    stored = read_arrays(args.map, what="correspondence map")
    if (args.black is None) != (args.white is None):
        raise EdofprojError("give both --black and --white (or neither: the map's dark and bright levels)")
    if args.black is not None:
        stored = {
            "dark": to_grey(read_rgb(args.black, what="black capture"), args.channel),
            "bright": to_grey(read_rgb(args.white, what="white capture"), args.channel),
        }
    if any(stored.get(key) is None or stored[key].shape != corr.camera_hw for key in ("dark", "bright")):
        raise EdofprojError(
            f"no dark and bright levels of the map's {corr.camera_hw[1]}x{corr.camera_hw[0]} camera "
            "(a map from 'edofproj procams decode', or --black and --white captures of that size)"
        )
    if args.black is not None and corr.valid.any():
        lift = float(np.median((stored["bright"] - stored["dark"])[corr.valid]))
        if lift <= 0:
            raise EdofprojError(
                f"the --white capture is not brighter than the --black one over the map's valid pixels (median "
                f"white - black {lift * 255:+.1f}/255): swapped? --black is the projector's black field, --white its white"
            )
    if args.no_blur and not args.psf_map:
        raise EdofprojError("--no-blur registers with a PSF map's offset: give --psf-map (or --offset-px without it)")
    psf_map = None
    if args.psf_map:  # the --channel's own map where the file has one (registration and blur), else its white one
        maps = load_psf_maps(args.psf_map)
        psf_map = maps.get(args.channel, maps.get("mean", next(iter(maps.values()))))
    image = to_grey(read_rgb(args.image, what="projector image"), args.channel)
    capture = to_grey(read_rgb(args.capture, what="capture"), args.channel)
    offset = tuple(args.offset_px) if args.offset_px is not None else None
    result = predict_capture(
        image, capture, corr, stored["dark"].astype(np.float64), stored["bright"].astype(np.float64),
        psf_map=psf_map, offset_px=offset, blur_psf=not args.no_blur,
    )  # fmt: skip
    if args.out:
        write_rgb_png(args.out, np.repeat(np.nan_to_num(result.image)[..., None], 3, axis=-1))
    blur = "with the PSF map" if psf_map is not None and not args.no_blur else "without blur"
    source = "--offset-px" if offset is not None else ("the PSF map's" if psf_map is not None else "no PSF map")
    o = result.offset_px
    print(
        f"prediction {blur} over {result.region.sum()} valid camera pixels: PSNR {result.psnr_db:.2f} dB, "
        f"SSIM {result.ssim:.3f} (capture gain {result.gain:.3f}, offset {result.offset:+.3f}; registered at "
        f"o = ({o[0]:+.2f}, {o[1]:+.2f}) projector px, {source})"
    )
    return 0
