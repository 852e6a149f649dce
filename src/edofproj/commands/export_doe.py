"""``edofproj export-doe``: lithography masks (GDSII), height map, profile CSV and manufacturability report."""

from __future__ import annotations

import argparse
import sys

from ..errors import EdofprojError
from ._common import add_config_options, add_design_source_argument, refuse_output_over


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export-doe",
        help="export a radial DOE for lithography (GDSII masks, height map, report)",
        description="Export a radial DOE design (a run directory holding doe.npz, or a design .npz) as binary "
        "lithography masks: profile.csv, a 16-bit height_map.png, masks.gds (mask j on layer j+1 with its alignment "
        "marks, aperture on layer 100, die outline on layer 101), mask previews and fab_report.md/.json (masks, "
        "tone, etch depths with their tolerance, die and substrate). Written all-or-nothing.",
    )
    add_design_source_argument(parser)
    parser.add_argument(
        "--out", required=True, metavar="DIR", help="output directory (new, empty, or a previous export)"
    )
    parser.add_argument(
        "--levels",
        type=int,
        default=None,
        metavar="N",
        help="re-quantize to N = 2^k levels (default: the design's own)",
    )
    parser.add_argument(
        "--critical-dimension-um",
        type=float,
        default=None,
        metavar="X",
        help="narrowest printable feature (default: fabrication.critical_dimension_um, 1 um)",
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help="write nothing and exit with code 3 if any feature is below the critical dimension",
    )
    parser.add_argument(
        "--map-px",
        type=int,
        default=None,
        metavar="N",
        help="height-map size in pixels (default: 2 px per narrowest zone, 512-4096)",
    )
    add_config_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..builtin_runs import run_label
    from ..fabrication.export import export_doe
    from ..fabrication.inputs import DesignInput
    from ..fabrication.profile import check_power_of_two_levels
    from ..fabrication.report import CriticalDimensionError

    if args.levels is not None:
        check_power_of_two_levels(args.levels)
    if args.critical_dimension_um is not None and not args.critical_dimension_um > 0:
        raise EdofprojError(f"--critical-dimension-um {args.critical_dimension_um:g} must be > 0")
    design = DesignInput.resolve(args.source)
    refuse_output_over(args.out, "--out", [("--config", args.config)], runs=[("RUN|DESIGN_FILE", args.source)])
    cfg = design.config(args.config, args.overrides)
    cd_um = (
        args.critical_dimension_um if args.critical_dimension_um is not None else cfg.fabrication.critical_dimension_um
    )
    try:
        report = export_doe(
            design.doe_file,
            args.out,
            levels=args.levels,
            critical_dimension_um=cd_um,
            arc_tolerance_um=cfg.fabrication.arc_tolerance_um,
            spectrum_cfg=cfg.spectrum,
            strict=args.strict,
            map_px=args.map_px,
            source=run_label(args.source),
            fabrication_cfg=cfg.fabrication,
        )
    except CriticalDimensionError as exc:
        print(f"edofproj: error: {exc}", file=sys.stderr)
        return CriticalDimensionError.exit_code
    verdict = "passes" if report["passes_critical_dimension"] else "FAILS"
    narrowest = min(
        (m["narrowest_feature_um"] for m in report["masks"] if m["narrowest_feature_um"]), default=float("nan")
    )
    print(
        f"wrote {args.out}: {report['levels']} levels, {report['masks_count']} masks, {report['zones']} zones; "
        f"narrowest feature {narrowest:.4g} um ({verdict} the {cd_um:g} um critical dimension); "
        f"efficiency {100 * report['efficiency']['design_wavelength']:.1f} % at the design wavelength"
    )
    return 0
