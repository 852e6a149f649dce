"""``edofproj procams evaluate``: score captured projections against their targets (paper Table 2).

    edofproj procams evaluate --targets DIR --captures DIR --calib calib.npz --out REPORT_DIR

Each method's raw captures are brought into projector space with the calibration and scored
against their targets; the report goes to REPORT_DIR.
"""

from __future__ import annotations

from .._common import refuse_output_over


def register(subparsers) -> None:
    """Add ``procams evaluate`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("evaluate", help="score captured projections against their targets (paper Table 2)")
    p.add_argument("--targets", required=True, help="folder of target images (projector output light)")
    p.add_argument(
        "--captures",
        required=True,
        help="folder with one sub-folder of raw captures per method (e.g. lens, lens+net, doe+net), named like the targets",
    )
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    p.add_argument("--out", required=True, help="report folder (report.md, report.html, comparison figure, scores)")
    p.add_argument("--weights-dir", default=None, help="folder of LPIPS/DISTS weights (default: the usual places)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...reporting.captures import evaluate_captures

    inputs = [("--targets", args.targets), ("--captures", args.captures), ("--calib", args.calib)]
    refuse_output_over(args.out, "--out", inputs + [("--weights-dir", args.weights_dir)])
    result = evaluate_captures(
        args.targets, args.captures, args.calib, args.out, weights_dir=args.weights_dir, overwrite=args.overwrite
    )
    for line in result.summary_lines():
        print(line)
    print(f"wrote {args.out} (report.md, report.html, comparison.png, scores.csv)")
    return 0
