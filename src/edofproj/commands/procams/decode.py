"""``edofproj procams decode``: structured-light captures -> the camera -> projector map.

    edofproj procams decode --lab lab.json [--root CAPTURES] --x SEQ [--y SEQ] [--planes N | --periods N] --out map.npz
    edofproj procams decode --lab lab.json --x GRAY --planes 7 --carry-from sessionA_map.npz --out map_b.npz
    edofproj procams decode --lab lab.json --x GRAY --planes 7 --edges [--carry-from A.npz] --out map_b.npz

Decodes a Gray-code or phase-shift sequence per axis (:mod:`edofproj.procams.structured_light`)
named in a lab manifest (:mod:`edofproj.procams.lab_manifest`) into ``map.npz``: the projector
point every camera pixel sees, NaN where the decoding is not valid, with the per-pixel dark and
bright levels. With both axes it prints the map's residual to a homography. ``--planes N`` decodes
a Gray code's first ``N`` planes, ``--periods N`` a phase shift's first ``N`` period counts (the
finer ones held out, e.g. to predict them). ``--carry-from``: the
camera moved since the session of that map; the map is carried over and anchored to this
session's code (:mod:`edofproj.procams.camera_motion`). ``--edges`` (Gray codes): the coordinate
along the code's axis from the stripes' edges, to a fraction of a pixel, over the surface they fit
(:mod:`edofproj.procams.edge_map`); with ``--carry-from``, the carried map gives the other axis.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over
from ._common import lab_inputs


def register(subparsers) -> None:
    """Add ``procams decode`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("decode", help="decode Gray-code / phase-shift captures into the camera->projector map")
    p.add_argument("--lab", required=True, help="lab manifest (lab.json) describing the captures")
    p.add_argument("--root", default=None, help="folder the manifest's files are in (default: the manifest's folder)")
    p.add_argument("--x", default=None, metavar="SEQ", help="sequence coding the projector's columns")
    p.add_argument("--y", default=None, metavar="SEQ", help="sequence coding the projector's rows")
    p.add_argument("--planes", type=int, default=None, metavar="N", help="decode only the first N Gray-code planes")
    p.add_argument(
        "--periods",
        type=int,
        default=None,
        metavar="N",
        help="decode only the first N period counts of a phase shift (the finest held out)",
    )
    p.add_argument(
        "--carry-from",
        default=None,
        metavar="MAP",
        help="map of an earlier session (both axes) to carry to this one, where the camera moved",
    )
    p.add_argument(
        "--edges",
        action="store_true",
        help="Gray code: the coordinate from the stripes' edges (sub-pixel), over the surface they fit",
    )
    p.add_argument("--out", required=True, help="output map .npz")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.lab_manifest import LabManifest, decode_sequence
    from ...procams.structured_light import CorrespondenceMap

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    inputs = [("--lab", args.lab), ("--root", args.root), ("--carry-from", args.carry_from)]
    inputs += lab_inputs(args.lab, args.root)
    refuse_output_over(args.out, "--out", inputs, file_output=True)
    if args.x is None and args.y is None:
        raise EdofprojError("give --x, --y or both: the sequences to decode")
    lab = LabManifest.load(args.lab, args.root)
    if args.x is not None and args.x == args.y:
        raise EdofprojError(
            f"--x and --y both name '{args.x}': give the sequence that codes the columns as --x and the one "
            "that codes the rows as --y"
        )
    for option, name, axis in (("--x", args.x, "x"), ("--y", args.y, "y")):
        declared = lab.sequence(name).axis if name else None
        if name and declared is not None and declared != axis:
            what = {"x": "columns", "y": "rows"}
            raise EdofprojError(
                f"{option} {name}: the lab manifest declares '{name}' on axis '{declared}' (it codes the projector's "
                f"{what[declared]}): give it as --{declared}" + (" (--x and --y swapped?)" if args.x and args.y else "")
            )
    kinds = {lab.sequence(name).kind for name in (args.x, args.y) if name}
    for option, value, kind in (("--planes", args.planes, "gray-code"), ("--periods", args.periods, "phase-shift")):
        if value is not None and kind not in kinds:
            other = "--periods N for a phase shift" if option == "--planes" else "--planes N for a Gray code"
            raise EdofprojError(
                f"{option} applies to a {kind.replace('-', ' ')}, and no sequence decoded is one ({other})"
            )

    def decoded(name):
        kind = lab.sequence(name).kind
        planes = args.planes if kind == "gray-code" else None
        periods = args.periods if kind == "phase-shift" else None
        return decode_sequence(lab, name, planes, periods)

    x = decoded(args.x) if args.x else None
    y = decoded(args.y) if args.y else None
    edges = {}
    if args.edges:
        edges = {
            axis: _edge_decoding(lab, name, axis, args.planes) for axis, name in (("x", args.x), ("y", args.y)) if name
        }
    decodings = [d for d in (x, y) if d is not None]
    # the levels saved: an edge decoding's, where the stripes without contrast have their neighbours'
    levels = [edges[a].decoding if a in edges else d for a, d in (("x", x), ("y", y)) if d is not None]
    dark = np.mean([d.dark for d in levels], axis=0)
    bright = np.mean([d.bright for d in levels], axis=0)
    if args.carry_from is not None:
        from ...fileio import read_arrays
        from ...procams.camera_motion import carry_map

        if len(decodings) != 1:
            raise EdofprojError("--carry-from anchors the carried map to one code: give --x or --y, not both")
        reference = CorrespondenceMap.load(args.carry_from)
        stored = read_arrays(args.carry_from, what="correspondence map")
        if "bright" not in stored or stored["bright"].shape != reference.camera_hw:
            raise EdofprojError(f"'{args.carry_from}' has no bright image to align the sessions with")
        axis = "x" if x is not None else "y"
        # aligned on what the camera saw fully lit: the decoding's own maximum per pixel
        seen = decodings[0].bright
        corr, motion = carry_map(reference, stored["bright"].astype(np.float64), decodings[0], axis, seen)
        if edges:
            corr = _with_edges(corr, edges)
        corr.save(args.out, dark=dark.astype(np.float32), bright=bright.astype(np.float32), camera_motion=motion)
        shift = motion[:2, 2]
        print(
            f"wrote {args.out}: map of '{args.carry_from}' carried to this session (camera moved by about "
            f"{shift[0]:+.1f}, {shift[1]:+.1f} px) and anchored to '{args.x or args.y}'"
            + (" (its coordinate from the stripes' edges)" if edges else "")
            + f": {corr.valid.mean():.1%} of the camera's pixels valid"
        )
        return 0
    if edges:
        x = edges["x"].decoding if "x" in edges else x
        y = edges["y"].decoding if "y" in edges else y
    corr = CorrespondenceMap.from_decodings(x, y, lab.projector_hw)
    corr.save(args.out, dark=dark.astype(np.float32), bright=bright.astype(np.float32))
    line = f"wrote {args.out}: {corr.valid.mean():.1%} of the camera's {corr.camera_hw[1]}x{corr.camera_hw[0]} px valid"
    if corr.is_complete:
        _, residual, inliers = corr.fit_homography()
        r = residual[inliers]
        line += (
            f"; residual to a homography (RANSAC, 1 px) over its {inliers.sum() / corr.valid.sum():.0%} inliers: "
            f"median {np.median(r):.2f}, 95 % {np.percentile(r, 95):.2f} projector px"
        )
    print(line)
    return 0


def _edge_decoding(lab, name: str, axis: str, planes: int | None):
    """:func:`edofproj.procams.edge_map.decode_gray_code_edges` of Gray-code sequence ``name``, its
    edges and blur printed."""
    from ...procams.edge_map import decode_gray_code_edges
    from ...procams.lab_manifest import read_gray_code
    from ...procams.structured_light import axis_length

    frames, inverse = read_gray_code(lab, name, planes)
    if inverse is not None:
        raise EdofprojError(f"--edges reads Gray codes without inverse patterns; '{name}' has them")
    result = decode_gray_code_edges(np.stack(frames), axis_length(lab.projector_hw, axis), lab.projector_hw)
    inliers = result.inliers
    error = np.abs(result.surface(result.edges.u, result.edges.v) - result.edges.coordinate)[inliers]
    print(
        f"'{name}': {len(inliers)} stripe edges, {inliers.mean():.0%} on one surface (residual median "
        f"{np.median(error):.2f}, 95 % {np.percentile(error, 95):.2f} projector px); blur along {axis} "
        f"{result.sigma_px:.2f} px; {result.decoding.valid.mean():.1%} of the camera's pixels valid"
    )
    return result


def _with_edges(corr, edges: dict):
    """The carried map with its coded axis from the edges, valid where both are known."""
    from ...procams.structured_light import CorrespondenceMap

    proj_x = edges["x"].decoding.coordinate if "x" in edges else corr.proj_x
    proj_y = edges["y"].decoding.coordinate if "y" in edges else corr.proj_y
    both = np.isfinite(proj_x) & np.isfinite(proj_y)
    return CorrespondenceMap(np.where(both, proj_x, np.nan), np.where(both, proj_y, np.nan), corr.projector_hw)
