"""``edofproj demo``: train, evaluate and report on built-in data, within a time budget.

    edofproj demo [--quick] [--out runs/demo]

Trains the ``cpu`` preset (the DOE with a U-Net, then a fresh U-Net for the DOE found, ``doe_net/``) and
the same U-Net without a DOE (``lens_net/``), plus the axicon, cubic-plate and OnlineProDeb baselines when
they fit the time budget (10 minutes; ``--quick``: 2) or end before ``doe_net``, and takes each baseline that does not fit from the runs
shipped with the package (``--retrain-baselines`` trains them all here). It then evaluates every
method on the held-out photographs and writes ``report.html`` (self-contained), ``report.md`` with
``figures/``, ``summary.md`` and ``metrics.csv`` into ``--out``. ``--pretrained`` starts from the
reference model shipped with the package (``builtin:cpu-doe-net``) instead of training ``doe+net``.
See :mod:`edofproj.application.demo`.
"""

from __future__ import annotations

import argparse

from ..application.durations import FULL_BUDGET_MIN, FULL_DURATION, QUICK_BUDGET_MIN, QUICK_DURATION
from ._common import add_set_option, parse_name_list, refuse_output_over

DEFAULT_PRETRAINED = "builtin:cpu-doe-net"
SUMMARY = f"train, evaluate and write a report on built-in data ({FULL_DURATION}; --quick: {QUICK_DURATION})"


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{value:g} must be > 0")
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help=SUMMARY,
        description=SUMMARY[0].upper() + SUMMARY[1:] + ".",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"a smoke run of {QUICK_DURATION}: few steps, tiny images; it checks that everything runs and judges "
        "nothing",
    )
    p.add_argument(
        "--out", default="runs/demo", metavar="DIR", help="output directory (new or empty; default runs/demo)"
    )
    p.add_argument("--config", default="cpu", help="training preset or YAML file (default: cpu)")
    p.add_argument(
        "--methods",
        default=None,
        help="only these methods (comma-separated; must include doe+net); their runs are then all trained",
    )
    add_set_option(p, help="override a config key of every run, e.g. --set train.refit_steps=300 (repeatable)")
    p.add_argument(
        "--budget-min",
        type=_positive_float,
        default=None,
        help=f"time budget in minutes (default {FULL_BUDGET_MIN}, --quick {QUICK_BUDGET_MIN}): optional baselines "
        "predicted not to fit are taken from the runs shipped with the package instead of trained",
    )
    p.add_argument(
        "--retrain-baselines",
        action="store_true",
        help="train every baseline here, whatever the budget (instead of taking the shipped runs)",
    )
    p.add_argument(
        "--workers",
        type=int,
        choices=(1, 2, 3, 4),
        default=2,
        help="training processes in parallel, one thread each (default 2)",
    )
    p.add_argument(
        "--pretrained",
        nargs="?",
        const=DEFAULT_PRETRAINED,
        default=None,
        metavar="RUN",
        help=f"start from a trained doe+net run instead of training it (default {DEFAULT_PRETRAINED}, the "
        "reference model shipped with the package); the baselines train with its configuration (its projector)",
    )
    p.add_argument("--no-timing", action="store_true", help="skip the per-frame timing stage")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..application.demo import demo_finished_message, run_demo
    from ..progress import StageProgress

    methods = parse_name_list(args.methods) if args.methods is not None else None
    refuse_output_over(args.out, "--out", [("--config", args.config)], runs=[("--pretrained", args.pretrained)])
    result = run_demo(
        args.out,
        quick=args.quick,
        config=args.config,
        methods=methods,
        overrides=args.overrides,
        workers=args.workers,
        budget_s=args.budget_min * 60 if args.budget_min else None,
        timing=not args.no_timing,
        progress=StageProgress("demo", enabled=not args.quiet),
        pretrained=args.pretrained,
        retrain_baselines=args.retrain_baselines,
    )
    print(demo_finished_message(result))
    return 0
