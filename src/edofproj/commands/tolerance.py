"""``edofproj tolerance``: Monte Carlo spread of the PSF energy concentration under fabrication errors."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ._common import add_config_options, add_design_source_argument, parse_number_list


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "tolerance",
        help="Monte Carlo of fabrication errors: PSF energy concentration across depth",
        description="Draw etch-depth errors (per mask), overlay errors between masks and (2-D engine) DOE decentre; "
        "report the spread of the energy in the central 3x3 pixels across depth. Writes tolerance.csv, "
        "tolerance.md, tolerance.json and tolerance.png into the run directory (or beside the design "
        "file, or --out). Defaults come from the fabrication config section.",
    )
    add_design_source_argument(parser)
    parser.add_argument("--trials", type=int, default=None, help="Monte Carlo trials (default 20)")
    parser.add_argument(
        "--etch-error-pct",
        type=float,
        default=None,
        metavar="P",
        help="etch depth error per mask, percent (1 sigma; default 3)",
    )
    parser.add_argument(
        "--misalignment-um",
        type=float,
        default=None,
        metavar="M",
        help="overlay error of each mask against mask 0, um (1 sigma per axis; default 0.5)",
    )
    parser.add_argument(
        "--decentre-um",
        type=float,
        default=None,
        metavar="D",
        help="DOE decentre against the lens, um (1 sigma per axis; needs --engine 2d; default 0)",
    )
    parser.add_argument(
        "--engine",
        choices=("radial", "2d"),
        default="radial",
        help="radial: exact radial proxy of overlay errors (fast); 2d: true lateral shifts (slow)",
    )
    parser.add_argument(
        "--depths-mm",
        default=None,
        metavar="LIST",
        help="depths, e.g. 300,500,800 or 300:800:100 (default: evaluation.depths_mm)",
    )
    parser.add_argument("--out", default=None, metavar="DIR", help="output directory")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--ssim-images",
        type=int,
        default=3,
        metavar="N",
        help="held-out images for the compensated SSIM when RUN has a trained network (default 3; 0 skips it)",
    )
    add_config_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..builtin_runs import require_output_outside
    from ..errors import EdofprojError
    from ..fabrication.inputs import DesignInput
    from ..fabrication.profile import RadialProfile
    from ..fabrication.tolerance import ToleranceSettings, run_tolerance
    from ..fabrication.tolerance_report import write_outputs

    if args.ssim_images < 0:
        raise EdofprojError(f"--ssim-images {args.ssim_images} must be >= 0 (0 skips the compensated SSIM)")
    design = DesignInput.resolve(args.source)
    if not args.out:
        require_output_outside(design.doe_file.parent, "--out")
    cfg = design.config(args.config, args.overrides)
    fab = cfg.fabrication

    def pick(value, default):
        return default if value is None else value

    settings = ToleranceSettings(
        trials=pick(args.trials, fab.tolerance_trials),
        etch_error_pct=pick(args.etch_error_pct, fab.etch_error_pct),
        misalignment_um=pick(args.misalignment_um, fab.misalignment_um),
        decentre_um=pick(args.decentre_um, fab.decentre_um),
        engine=args.engine,
        seed=args.seed,
    ).validate()
    depths_mm = parse_number_list(args.depths_mm, "--depths-mm") if args.depths_mm else cfg.evaluation.depths_mm
    profile = RadialProfile.from_file(design.doe_file)

    def progress(done: int, total: int) -> None:
        print(f"\rtrial {done}/{total}", end="" if done < total else "\n", file=sys.stderr, flush=True)

    evaluate_ssim = None
    if design.run_dir is not None and args.ssim_images > 0 and (design.run_dir / "checkpoints" / "last.pt").is_file():
        import torch

        from ..data import build_test_images
        from ..fabrication.tolerance import compensated_ssim_evaluator
        from ..runs import load_run

        trained = load_run(design.run_dir)
        held_out = build_test_images(cfg.data, size=128)
        if args.ssim_images > len(held_out):
            raise EdofprojError(
                f"--ssim-images {args.ssim_images}: the run has {len(held_out)} held-out images; give at most that"
            )
        images = torch.stack([img for _, img in held_out[: args.ssim_images]])
        evaluate_ssim = compensated_ssim_evaluator(trained.net, cfg, images, settings.engine)
        print(f"compensated SSIM on {len(images)} held-out images with the run's network", file=sys.stderr)
    result = run_tolerance(
        profile,
        cfg,
        settings,
        np.asarray(depths_mm, dtype=float) * 1e-3,
        evaluate_ssim=evaluate_ssim,
        progress=progress if sys.stderr.isatty() else None,
    )
    out_dir = args.out or design.run_dir or design.doe_file.parent
    paths = write_outputs(result, out_dir, source=args.source)
    from ..methods.depth_ranges import format_span_mm

    p05, p50, _ = result.percentiles()
    worst, (near, far) = headline_depth_index(result.depths_m * 1e3, p05, cfg)
    print(
        f"wrote {', '.join(str(p) for p in paths)}; energy in 3x3 px at {result.depths_m[worst] * 1e3:.0f} mm "
        f"(the worst depth of the scored {format_span_mm(near, far)} mm): "
        f"nominal {result.nominal[worst]:.4f}, median {p50[worst]:.4f}, 5th percentile {p05[worst]:.4f}"
    )
    return 0


def headline_depth_index(depths_mm, p05, cfg) -> tuple[int, tuple[float, float]]:
    """The index of the depth the headline reports -- the lowest 5th percentile among the depths in the run's
    scored range (``evaluation.score_range_mm``, else its training range; all depths when none lies in it,
    :func:`edofproj.methods.depth_ranges.scored_range_mm`) -- and that range as the depths cover it."""
    from ..methods.compensators import score_range_mm
    from ..methods.depth_ranges import scored_range_mm

    depths_mm = np.asarray(depths_mm, dtype=float)
    near, far = scored_range_mm(depths_mm.tolist(), score_range_mm(cfg))
    inside = np.flatnonzero((depths_mm >= near - 1e-9) & (depths_mm <= far + 1e-9))
    return int(inside[np.argmin(np.asarray(p05)[inside])]), (near, far)
