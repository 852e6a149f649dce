"""``edofproj summarize``: mean ± spread over several evaluations of the same methods.

    edofproj summarize runs/seed0/eval runs/seed1/eval runs/seed2/eval [--range-mm 300:800] [--metric ssim]

Each argument is an output directory of ``edofproj evaluate`` (or its ``metrics.csv``), e.g. one
per training seed, scored on the same images and depths (refused otherwise, as are incomplete or
truncated files, NA scores, scores outside their metric's range (inf, NaN, an SSIM outside
[-1, 1]), an evaluation given twice (a link, a copy) and an unknown ``--reference``). Prints, as Markdown, each method's mean
and worst-depth score over ``--range-mm`` as mean ± standard deviation over the evaluations, and
the paired difference to ``--reference`` (:func:`edofproj.reporting.tables.run_spread_table`);
then the same for the CIEDE2000 colour difference (``de2000``, ``de2000_p95``; lower is better)
where every evaluation has those columns.
"""

from __future__ import annotations

from ._common import parse_number_list


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "summarize",
        help="mean ± spread over several evaluations (e.g. training seeds) of the same methods",
        description=__doc__.split("\n")[0],
    )
    p.add_argument("evaluations", nargs="+", metavar="EVAL", help="evaluate output directories or metrics.csv files")
    p.add_argument("--range-mm", default="300:800", help="depth range scored, NEAR:FAR in mm (default 300:800)")
    p.add_argument("--metric", default="ssim", help="metric column of metrics.csv (default ssim)")
    p.add_argument("--reference", default="doe+net", help="method the others are compared with (default doe+net)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..errors import EdofprojError
    from ..evaluation.results import COLOUR_METRICS, MetricsTable
    from ..reporting.document import markdown_table
    from ..reporting.tables import check_like_runs, run_spread_table

    parts = str(args.range_mm).split(":")
    if len(parts) != 2:
        raise EdofprojError(f"--range-mm '{args.range_mm}' must be NEAR:FAR in mm, e.g. 300:800")
    near, far = parse_number_list(parts[0], "--range-mm")[0], parse_number_list(parts[1], "--range-mm")[0]
    if not 0 < near <= far:
        raise EdofprojError(f"--range-mm '{args.range_mm}' needs 0 < NEAR <= FAR")
    tables: dict = {}
    seen: dict = {}  # resolved path, then contents -> the argument that gave them
    for item in args.evaluations:
        path = Path(item)
        csv_path = path / "metrics.csv" if path.is_dir() else path
        if not csv_path.is_file():
            raise EdofprojError(f"'{item}' has no metrics.csv (an output directory of edofproj evaluate)")
        contents = csv_path.read_bytes()
        for key, how in ((csv_path.resolve(), "is the same file as"), (contents, "holds the same scores as")):
            if (
                key in seen
            ):  # a link, another spelling or a copy of one evaluation: counted once it would fake agreement
                raise EdofprojError(f"'{item}' {how} '{seen[key]}': give each evaluation once")
            seen[key] = item
        tables[str(csv_path)] = MetricsTable.read_csv(csv_path, ("method", "depth_mm", "image"))
    check_like_runs(tables, (near, far), args.metric, args.reference)
    print(markdown_table(run_spread_table(tables, (near, far), args.metric, args.reference)))
    for colour in COLOUR_METRICS:  # colour fidelity beside the chosen metric, where every table has it
        if colour != args.metric and all(colour in table.metrics for table in tables.values()):
            print()
            print(markdown_table(run_spread_table(tables, (near, far), colour, args.reference)))
    return 0
