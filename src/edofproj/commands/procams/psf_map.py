"""``edofproj procams psf-map``: the PSF across the surface from a captured grid of single-pixel dots.

    edofproj procams psf-map --lab lab.json --dots SEQ --map map.npz --out psf_map.npz [--figure psf_map.png]

Fits an anisotropic Gaussian (projector pixels) to every dot, saturated and black-clipped
samples censored, estimates the decoded map's offset, and writes the map of covariances
(:mod:`edofproj.procams.psf_map`). The map must be of the same camera pose as the dot capture.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over


def register(subparsers) -> None:
    """Add ``procams psf-map`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("psf-map", help="PSF map (anisotropic Gaussians, projector px) from single-pixel dots")
    p.add_argument("--lab", required=True, help="lab manifest (lab.json)")
    p.add_argument("--root", default=None, help="folder the manifest's files are in (default: the manifest's folder)")
    p.add_argument("--dots", required=True, metavar="SEQ", help="the dot-grid sequence")
    p.add_argument("--index", type=int, default=0, help="which of the sequence's captures (0: the first)")
    p.add_argument("--map", required=True, help="camera->projector map of the same camera pose ('procams decode')")
    p.add_argument("--every", type=int, default=1, metavar="N", help="fit every N-th dot in each direction (1)")
    p.add_argument("--out", required=True, help="output PSF map .npz")
    p.add_argument("--figure", default=None, metavar="PNG", help="also draw sigma_x, sigma_y and the angle")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.lab_manifest import LabManifest, to_grey
    from ...procams.psf_map import DotGrid, measure_psf_map
    from ...procams.structured_light import CLIPPED_BLACK, SATURATED, CorrespondenceMap

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    inputs = [("--lab", args.lab), ("--root", args.root), ("--map", args.map)]
    for option, output in (("--out", args.out), ("--figure", args.figure)):
        refuse_output_over(output, option, inputs, file_output=True)
    if args.every < 1:
        raise EdofprojError(f"--every {args.every} must be >= 1")
    lab = LabManifest.load(args.lab, args.root)
    seq = lab.sequence(args.dots)
    if seq.kind != "dots":
        raise EdofprojError(f"sequence '{args.dots}' is of kind '{seq.kind}', not 'dots'")
    if not 0 <= args.index < len(seq.files):
        raise EdofprojError(f"--index {args.index} is not 0..{len(seq.files) - 1}")
    corr = CorrespondenceMap.load(args.map)
    rgb = lab.read_rgb(seq.files[args.index]).astype(np.float64)
    grey = to_grey(rgb, lab.channel)
    saturated = np.asarray((rgb >= SATURATED).any(axis=-1))
    clipped = np.asarray((rgb <= CLIPPED_BLACK).all(axis=-1))
    grid = DotGrid.covering(lab.projector_hw, seq.spacing_px, seq.origin_px)
    psf_map, fits = measure_psf_map(grey, corr, grid, every=args.every, saturated=saturated, clipped=clipped)
    psf_map.save(args.out)
    censored = sum(f.censored for f in fits.values()) / max(sum(f.samples for f in fits.values()), 1)
    fitted = psf_map.fitted
    print(
        f"wrote {args.out}: {len(fits)} dots fitted ({censored:.0%} of their samples censored); map offset "
        f"o = ({psf_map.offset_px[0]:+.2f}, {psf_map.offset_px[1]:+.2f}) projector px; median sigma_x "
        f"{np.median(psf_map.sigma_x[fitted]):.2f} px, sigma_y {np.median(psf_map.sigma_y[fitted]):.2f} px, "
        f"major axis at {np.median(psf_map.angle_deg[fitted]):.0f} deg"
    )
    if args.figure:
        from ...procams.psf_map import plot_psf_map

        plot_psf_map(psf_map, args.figure)
        print(f"wrote {args.figure}")
    return 0
