"""``edofproj procams psf-map``: the PSF across the surface from a captured grid of single-pixel dots.

    edofproj procams psf-map --lab lab.json --dots SEQ [SEQ ...] --map map.npz --out psf_map.npz [--figure psf_map.png]
    edofproj procams psf-map --lab lab.json --code GRAY --planes N --map map.npz [--like psf_map.npz] --out psf_b.npz
    edofproj procams psf-map --lab lab.json --dots SEQ --background SEQ --map map.npz --model rank-profile --out kmap.npz

Fits an anisotropic Gaussian (projector pixels) to every dot, saturated and black-clipped
samples censored, estimates the decoded map's offset, and writes the map of covariances
(:mod:`edofproj.procams.psf_map`). The map must be of the same camera pose as the dot capture.
Several ``--dots`` sequences of different colours (their ``channel`` in the lab manifest: white dots
``mean``, or ``red``, ``green``, ``blue``) give one map per colour in one file.
``--code``: the PSF's width along a Gray code's axis, measured from the first ``N`` planes' captures
themselves through a sub-pixel map (``procams decode --edges``), per cell of projector points; the
other components from the ``--like`` PSF map, else an isotropic Gaussian
(:mod:`edofproj.procams.code_blur`).
``--model rank-profile``: no shape is fitted; each dot's window gives its rank profile (the kernel
estimator of Li et al., TII 2020) and every node of the map keeps the mean profile of the dots within
``--smooth-px`` (default: the box that best predicts the dots it leaves out; a kernel map, :mod:`edofproj.procams.kernel_map`; 8-bit captures).
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over
from ._common import lab_inputs


def register(subparsers) -> None:
    """Add ``procams psf-map`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("psf-map", help="PSF map (anisotropic Gaussians, projector px) from single-pixel dots")
    p.add_argument("--lab", required=True, help="lab manifest (lab.json)")
    p.add_argument("--root", default=None, help="folder the manifest's files are in (default: the manifest's folder)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--dots", metavar="SEQ", nargs="+",
                        help="the dot-grid sequence(s): one map per colour (the sequences' 'channel')")  # fmt: skip
    source.add_argument("--code", metavar="SEQ", help="a Gray-code sequence: the width along its axis")
    p.add_argument("--planes", type=int, default=None, metavar="N", help="--code: use the first N planes (all)")
    p.add_argument("--like", default=None, metavar="PSF_MAP", help="--code: the components it does not measure")
    p.add_argument("--index", type=int, default=0, help="which of the sequence's captures (0: the first)")
    p.add_argument("--map", required=True, help="camera->projector map of the same camera pose ('procams decode')")
    p.add_argument("--every", type=int, default=1, metavar="N", help="fit every N-th dot in each direction (1)")
    p.add_argument("--model", choices=("gaussian", "rank-profile"), default="gaussian",
                   help="--dots: fit a Gaussian to every dot (default), or keep the dots' rank profiles (a kernel map)")  # fmt: skip
    p.add_argument(
        "--background", default=None, metavar="SEQ", help="--model rank-profile: a capture of the projector dark"
    )
    p.add_argument("--smooth-px", type=float, default=None, metavar="PX",
                   help="--model rank-profile: side of the box of dots averaged at each node (default: by leave-one-out)")  # fmt: skip
    p.add_argument("--out", required=True, help="output PSF map .npz")
    p.add_argument("--figure", default=None, metavar="PNG", help="also draw sigma_x, sigma_y and the angle")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.lab_manifest import LabManifest, censored_samples, to_grey
    from ...procams.psf_map import DotGrid, measure_psf_map, save_psf_maps, summary
    from ...procams.structured_light import CorrespondenceMap
    from ...progress import StageProgress

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    inputs = [("--lab", args.lab), ("--root", args.root), ("--map", args.map), ("--like", args.like)]
    inputs += lab_inputs(args.lab, args.root)
    for option, output in (("--out", args.out), ("--figure", args.figure)):
        refuse_output_over(output, option, inputs, file_output=True)
    if args.code is not None:
        return _from_code(args)
    if args.like is not None or args.planes is not None:
        raise EdofprojError("--like and --planes go with --code")
    if args.model != "rank-profile" and (args.background is not None or args.smooth_px is not None):
        raise EdofprojError("--background and --smooth-px go with --model rank-profile")
    if args.every < 1:
        raise EdofprojError(f"--every {args.every} must be >= 1")
    lab = LabManifest.load(args.lab, args.root)
    sequences = [lab.sequence(name) for name in args.dots]
    channels = [lab.channel_of(seq) for seq in sequences]
    for seq, channel in zip(sequences, channels):
        if seq.kind != "dots":
            raise EdofprojError(f"sequence '{seq.name}' is of kind '{seq.kind}', not 'dots'")
        if channels.count(channel) > 1:
            raise EdofprojError(
                f"--dots {' '.join(args.dots)}: {channels.count(channel)} sequences are of channel '{channel}'; "
                "give one per colour (a sequence's colour is its 'channel' in the lab manifest)"
            )
        if not 0 <= args.index < len(seq.files):
            raise EdofprojError(f"--index {args.index} is not 0..{len(seq.files) - 1} (sequence '{seq.name}')")
    corr = CorrespondenceMap.load(args.map)
    if args.model == "rank-profile":
        return _rank_profile(args, lab, sequences, channels, corr)
    progress = StageProgress("psf-map")
    maps = []
    for seq, channel in zip(sequences, channels):
        rgb = lab.read_rgb(seq.files[args.index]).astype(np.float64)
        saturated, clipped = censored_samples(rgb, channel)
        grid = DotGrid.covering(lab.projector_hw, seq.spacing_px, seq.origin_px)
        psf_map, fits = measure_psf_map(
            to_grey(rgb, channel), corr, grid, every=args.every, saturated=saturated, clipped=clipped,
            channel=channel, progress=progress,
        )  # fmt: skip
        maps.append(psf_map)
        censored = sum(f.censored for f in fits.values()) / max(sum(f.samples for f in fits.values()), 1)
        print(
            f"{channel} ('{seq.name}'): {len(fits)} dots fitted ({censored:.0%} of their samples censored); map offset "
            f"o = ({psf_map.offset_px[0]:+.2f}, {psf_map.offset_px[1]:+.2f}) projector px; {summary(psf_map)}"
        )
    save_psf_maps(args.out, maps)
    print(f"wrote {args.out}: {', '.join(m.channel for m in maps)}")
    return _write_figure(maps, args.figure)


def _rank_profile(args, lab, sequences, channels, corr) -> int:
    """``--model rank-profile``: the kernel map of the dot captures (module docstring)."""
    from ...procams.capture_io import read_rgb_counts
    from ...procams.kernel_map import measure_kernel_map, summary
    from ...procams.psf_map import DotGrid

    if args.every != 1:
        raise EdofprojError("--every goes with --model gaussian (a kernel map averages every dot)")
    if args.figure:
        raise EdofprojError("--figure draws a Gaussian map's widths and goes with --model gaussian")
    grids = {(tuple(s.spacing_px), tuple(s.origin_px)) for s in sequences}
    if len(grids) != 1:
        raise EdofprojError("--model rank-profile takes dot sequences of one grid (spacing and origin)")
    if tuple(corr.projector_hw) != tuple(lab.projector_hw):
        raise EdofprojError(f"the map's projector {corr.projector_hw} is not the manifest's {lab.projector_hw}")
    captures = [
        (read_rgb_counts(lab.root / s.files[args.index], what="dot capture"), c) for s, c in zip(sequences, channels)
    ]
    background = None
    if args.background is not None:
        back = lab.sequence(args.background)
        background = read_rgb_counts(lab.root / back.files[0], what="background capture")
        if background.shape != captures[0][0].shape:
            raise EdofprojError(f"the background capture is {background.shape[1]}x{background.shape[0]}, "
                                f"the dots' {captures[0][0].shape[1]}x{captures[0][0].shape[0]}")  # fmt: skip
    grid = DotGrid.covering(lab.projector_hw, sequences[0].spacing_px, sequences[0].origin_px)
    kernel_map = measure_kernel_map(captures, corr, grid, background, smooth_px=args.smooth_px)
    kernel_map.save(args.out)
    o = kernel_map.offset_px
    print(f"wrote {args.out}: kernel map of {', '.join(kernel_map.channels)} (rank profiles); map offset "
          f"o = ({o[0]:+.2f}, {o[1]:+.2f}) projector px; {summary(kernel_map)}")  # fmt: skip
    if kernel_map.leave_one_out:
        tried = ", ".join(f"{side:g} px {error:.3g}" for side, error in kernel_map.leave_one_out.items())
        print(f"box by leave-one-out: {kernel_map.smooth_px:g} px (error of the left-out dots' kernels: {tried})")
    return 0


def _from_code(args) -> int:
    from ...fileio import read_arrays
    from ...procams.code_blur import blur_psf_map, measure_code_blur
    from ...procams.lab_manifest import LabManifest, read_gray_code
    from ...procams.psf_map import PSFMap
    from ...procams.structured_light import CorrespondenceMap

    lab = LabManifest.load(args.lab, args.root)
    seq = lab.sequence(args.code)
    frames, _ = read_gray_code(lab, args.code, args.planes)
    corr = CorrespondenceMap.load(args.map)
    stored = read_arrays(args.map, what="correspondence map")
    if any(stored.get(key) is None or stored[key].shape != corr.camera_hw for key in ("dark", "bright")):
        raise EdofprojError(f"'{args.map}' has no dark and bright levels: make it with 'edofproj procams decode'")
    if tuple(corr.projector_hw) != tuple(lab.projector_hw):
        raise EdofprojError(f"the map's projector {corr.projector_hw} is not the manifest's {lab.projector_hw}")
    reference = PSFMap.load(args.like) if args.like else None
    axis = str(seq.axis)
    fit = measure_code_blur(np.stack(frames), corr, axis, stored["dark"], stored["bright"])
    psf_map = blur_psf_map(fit, axis, lab.projector_hw, reference)
    psf_map.save(args.out)
    fitted = fit.cell_sigma_px[fit.fitted]
    others = f"the other components from '{args.like}'" if reference is not None else "isotropic"
    print(
        f"wrote {args.out}: blur along {axis} from {len(frames)} planes of '{args.code}': {fit.sigma_px:.2f} px "
        f"over the surface; per cell (projector {fit.xs[1] - fit.xs[0]:.0f} px) {np.percentile(fitted, 10):.2f} "
        f"to {np.percentile(fitted, 90):.2f} px (10-90 %), {others}"
    )
    return _write_figure(psf_map, args.figure)


def _write_figure(psf_map, path) -> int:
    """Draw ``psf_map`` to ``path`` when one was asked for (``--figure``); the command's exit code."""
    if path:
        from ...procams.psf_map import plot_psf_map

        plot_psf_map(psf_map, path)
        print(f"wrote {path}")
    return 0
