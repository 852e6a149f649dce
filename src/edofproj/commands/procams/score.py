"""``edofproj procams score``: score compensations in simulation as Li et al. (IEEE TII 2020) do.

    edofproj procams score --psf-map PSF_MAP --image ORIGINAL --compensation COMP [COMP ...] [--crop y0,y1,x0,x1]
    edofproj procams score --lab lab.json --dots SEQ --map map.npz [--background SEQ] [--offset-px X Y]
                           [--kernels script|per-channel|both] --image ORIGINAL --compensation COMP [...] [--crop ...]

Blurs the original projector image (the "normal projection") and each compensation with the measured
blur, rounds the results to 8 bits, and prints SSIM, PSNR and RMSE of each against the original over
the crop, as their ``metrics_for_vgroove.m`` does (:mod:`edofproj.procams.protocol_score`: MATLAB's
SSIM of the RGB array as a volume, PSNR with the normal projection's peak, RMSE in 8-bit counts).
The blur: the PSF map's (``procams psf-map``; a colour's own map where the file has it), or their
kernels (``--lab``/``--dots``: 11x11 windows of the dot capture in projector space, rearranged by
rank and interpolated between dots, :mod:`edofproj.procams.lab_kernels`), either as their script
applies them (the red channel's kernels for all three colours) or each colour its own.
``--crop``: 0-based, end excluded (their 1-based inclusive ``top_left = [r0, c0]``,
``bottom_right = [r1, c1]`` is ``r0-1,r1,c0-1,c1``); default the whole image.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ...errors import EdofprojError

KERNEL_MODES = ("script", "per-channel", "both")


def register(subparsers) -> None:
    """Add ``procams score`` to the ``procams`` subcommands."""
    p = subparsers.add_parser(
        "score", help="score compensations in simulation (Li et al.'s protocol: SSIM, PSNR, RMSE in a crop)"
    )
    p.add_argument("--image", required=True, help="the original projector image (8-bit RGB)")
    p.add_argument("--compensation", required=True, nargs="+", metavar="COMP", help="compensation images to score")
    p.add_argument("--crop", default=None, metavar="y0,y1,x0,x1", help="rows y0..y1-1, columns x0..x1-1 (0-based)")
    blur = p.add_mutually_exclusive_group(required=True)
    blur.add_argument("--psf-map", default=None, help="blur with this PSF map ('procams psf-map')")
    blur.add_argument("--dots", default=None, metavar="SEQ", help="blur with their kernels from this dot sequence")
    p.add_argument("--lab", default=None, help="--dots: the lab manifest (lab.json)")
    p.add_argument("--root", default=None, help="--dots: folder of the manifest's files (default: its folder)")
    p.add_argument("--index", type=int, default=0, help="--dots: which of the sequence's captures (0: the first)")
    p.add_argument("--map", default=None, help="--dots: camera->projector map of the dot capture ('procams decode')")
    p.add_argument("--background", default=None, metavar="SEQ", help="--dots: capture subtracted from the dots")
    p.add_argument(
        "--offset-px",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("X", "Y"),
        help="--dots: the map's offset o (camera pixels see P - o; 1 1 rounds as their 1-based decoding does)",
    )
    p.add_argument(
        "--kernels",
        default="both",
        choices=KERNEL_MODES,
        help="--dots: their script's (red kernels for R, G, B), per channel, or both tables (both)",
    )
    p.add_argument(
        "--optimum",
        type=int,
        default=None,
        metavar="N",
        help="also score the least-squares optimum under the same blur (N iterations of box-constrained FISTA)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.capture_io import read_rgb_counts
    from ...procams.protocol_score import (
        Crop,
        image_counts,
        least_squares_optimum,
        psf_map_protocol_blur,
        score_compensations,
        to_uint8,
    )

    lab_options = ("--lab", args.lab), ("--map", args.map), ("--background", args.background), ("--root", args.root)
    if args.psf_map is not None:
        given = [name for name, value in lab_options if value is not None]
        if given:
            raise EdofprojError(f"{', '.join(given)} go with --dots (their kernels), not --psf-map")
    elif args.lab is None or args.map is None:
        raise EdofprojError("--dots needs --lab (the manifest) and --map (the dot capture's decoded map)")
    original = image_counts(read_rgb_counts(args.image, what="--image"))
    compensations = [(Path(c).name, image_counts(read_rgb_counts(c, what="--compensation"))) for c in args.compensation]
    crop = Crop.parse(args.crop) if args.crop else Crop(0, original.shape[0], 0, original.shape[1])
    crop.check(original.shape[:2])
    if args.optimum is not None and args.optimum < 1:
        raise EdofprojError(f"--optimum {args.optimum} must be >= 1 (iterations)")
    if args.psf_map is not None:
        tables = [psf_map_protocol_blur(args.psf_map, original.shape[:2])]
    else:
        tables = _lab_blurs(args, original.shape[:2])
    H, W = crop.y1 - crop.y0, crop.x1 - crop.x0
    print(f"crop rows {crop.y0}..{crop.y1 - 1}, columns {crop.x0}..{crop.x1 - 1} ({W}x{H} px, 3 colours)")
    width = max(len("normal projection"), *(len(name) for name, _ in compensations))
    for blur in tables:
        scored = list(compensations)
        if args.optimum is not None:
            start = time.perf_counter()
            optimum, tail = least_squares_optimum(original, blur, crop, args.optimum)
            seconds = time.perf_counter() - start
            name = f"least-squares optimum ({args.optimum} it., {seconds:.0f} s, last tenth {100 * tail:.2f} %)"
            scored.append((name, to_uint8(optimum)))
        width = max(width, *(len(name) for name, _ in scored))
        rows = score_compensations(original, scored, blur.blur, crop)
        print(f"blur: {blur.title}")
        print(f"  {'':<{width}}  {'SSIM':>7}  {'PSNR (dB)':>9}  {'RMSE':>7}")
        for row in rows:
            print(f"  {row.name:<{width}}  {row.ssim:7.4f}  {row.psnr_db:9.2f}  {row.rmse:7.3f}")
    return 0


def _lab_blurs(args, hw):
    from ...procams.capture_io import read_rgb_counts
    from ...procams.lab_kernels import capture_to_projector, kernel_field
    from ...procams.lab_manifest import LabManifest
    from ...procams.protocol_score import lab_protocol_blur
    from ...procams.psf_map import DotGrid
    from ...procams.structured_light import CorrespondenceMap

    lab = LabManifest.load(args.lab, args.root)
    seq = lab.sequence(args.dots)
    if seq.kind != "dots":
        raise EdofprojError(f"sequence '{args.dots}' is of kind '{seq.kind}', not 'dots'")
    if not 0 <= args.index < len(seq.files):
        raise EdofprojError(f"--index {args.index} is not 0..{len(seq.files) - 1}")
    if tuple(lab.projector_hw) != tuple(hw):
        raise EdofprojError(
            f"--image is {hw[1]}x{hw[0]}, the manifest's projector {lab.projector_hw[1]}x{lab.projector_hw[0]}"
        )
    corr = CorrespondenceMap.load(args.map)
    if tuple(corr.projector_hw) != tuple(hw):
        raise EdofprojError(
            f"--map is of a {corr.projector_hw[1]}x{corr.projector_hw[0]} projector, --image {hw[1]}x{hw[0]}"
        )
    capture = read_rgb_counts(lab.root / seq.files[args.index], what="dot capture")
    background = None
    if args.background is not None:
        back = lab.sequence(args.background)
        background = read_rgb_counts(lab.root / back.files[0], what="background capture")
        if background.shape != capture.shape:
            raise EdofprojError(
                f"the background capture is {background.shape[1]}x{background.shape[0]}, "
                f"the dots' {capture.shape[1]}x{capture.shape[0]}"
            )
    if capture.dtype != np.uint8:
        raise EdofprojError("their kernels are defined on 8-bit captures; the dot capture is not 8-bit")
    dots = capture_to_projector(capture, corr, tuple(args.offset_px), background)
    grid = DotGrid.covering(lab.projector_hw, seq.spacing_px, seq.origin_px)
    red = kernel_field(dots[..., 0], grid)
    tables = []
    if args.kernels in ("script", "both"):
        title = "their kernels as their script applies them (the red channel's for R, G and B)"
        tables.append(lab_protocol_blur([red] * 3, title))
    if args.kernels in ("per-channel", "both"):
        fields = [red] + [kernel_field(dots[..., c], grid) for c in (1, 2)]
        tables.append(lab_protocol_blur(fields, "their kernels, each colour its own"))
    return tables
