"""``edofproj train``: jointly train the DOE and the compensation network (a run directory).

    edofproj train --config cpu --out runs/cpu [--set train.steps=800 ...] [--steps N] [--resume]
                   [--stop-after N] [--time-budget SECONDS]
    torchrun --nproc_per_node=2 -m edofproj.cli train --config cpu --out runs/cpu_ddp

Writes ``config.yaml``, ``train_log.csv``, ``checkpoints/``, ``doe.npz`` and ``figures/`` into
``--out`` (see :mod:`edofproj.runs`). ``--resume`` continues a run exactly from its
last checkpoint; without ``--config`` it uses the run's own ``config.yaml``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..config import load_config
from ._common import add_config_options


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train a DOE and compensation network end to end",
        description="Jointly train the DOE and the compensation network (paper Fig. 2). "
        "Runs data-parallel under torchrun.",
    )
    add_config_options(parser)
    parser.add_argument("--out", required=True, metavar="DIR", help="run directory (new, or existing with --resume)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    parser.add_argument(
        "--steps",
        type=_positive_int,
        default=None,
        metavar="N",
        help="optimizer steps of the run's first phase (shortcut for --set train.steps=N; a second phase of "
        "train.refit_steps follows where the config has one)",
    )
    parser.add_argument(
        "--stop-after",
        type=_positive_int,
        default=None,
        metavar="N",
        help="end this session after step N (checkpointed; continue later with --resume)",
    )
    parser.add_argument(
        "--time-budget",
        type=_positive_seconds,
        default=None,
        metavar="SECONDS",
        help="end this session before the first step that would end more than SECONDS after it began "
        "(checkpointed; continue later with --resume)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be >= 1")
    return value


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number of seconds > 0")
    return value


def describe_phases(cfg) -> str:
    """The run's length phase by phase: ``--steps``/``train.steps`` is the first phase's length, and a
    ``train.refit_steps`` phase follows where the config has one (said, so that a short ``--steps`` is not
    mistaken for the whole run)."""
    from ..training.phases import total_steps, training_phases

    phases = training_phases(cfg)
    if len(phases) == 1:
        return f"{total_steps(cfg):,} steps in one phase ({phases[0].name})"
    parts = " + ".join(f"{p.end - p.offset:,} {p.name}" for p in phases)
    return (
        f"{total_steps(cfg):,} steps: {parts} (train.steps sets the first phase, train.refit_steps the second; "
        "--set train.refit_steps=0 for one phase)"
    )


def resumed_changes(run_dir: Path, cfg) -> str:
    """``key old -> new, ...`` of the keys a ``--resume`` may change (:data:`edofproj.runs.RESUMABLE_KEYS`:
    the run's length, checkpointing, threads, device) that ``cfg`` changes in the run's ``config.yaml``;
    empty when none does (or the run has no ``config.yaml``)."""
    from ..config import flatten_config
    from ..runs import CONFIG_NAME, RESUMABLE_KEYS, saved_config

    if not (run_dir / CONFIG_NAME).is_file():
        return ""
    old, new = flatten_config(saved_config(run_dir)), flatten_config(cfg)
    return ", ".join(f"{k} {old.get(k)!r} -> {new.get(k)!r}" for k in RESUMABLE_KEYS if old.get(k) != new.get(k))


def run(args: argparse.Namespace) -> int:
    from ..data import describe_training_data
    from ..runs import saved_config
    from ..training.phases import total_steps
    from ..training.trainer import train

    overrides = list(args.overrides or [])
    if args.steps is not None:
        overrides.append(f"train.steps={args.steps}")
    out = Path(args.out)
    if args.resume and args.config is None:
        cfg = saved_config(out, overrides)
    else:
        cfg = load_config(args.config, overrides)
        if not args.resume and cfg.name == "run":
            cfg.name = out.name or "run"
    if args.resume and args.config is not None and cfg.name == "run":
        cfg.name = saved_config(out).name
    if int(os.environ.get("RANK", "0")) == 0:
        if args.resume:
            changes = resumed_changes(out, cfg)
            if changes:
                print(f"{out}: --resume changes the run's {changes}; config.yaml is rewritten with them", flush=True)
        print(describe_training_data(cfg.data), flush=True)
        print(f"{out}: {describe_phases(cfg)}", flush=True)
    result = train(
        cfg,
        out,
        resume=args.resume,
        stop_after=args.stop_after,
        progress=not args.quiet,
        time_budget_s=args.time_budget,
    )
    if int(os.environ.get("RANK", "0")) == 0:
        if result.step == result.start_step and result.stopped_at_time_budget:
            print(f"{out}: the time budget ended before step {result.step + 1}: nothing trained in this session")
        elif result.step == result.start_step:
            print(
                f"{out}: nothing to do, the run is at step {result.step} of {total_steps(cfg)} "
                f"(raise --steps to continue)"
            )
        else:
            print(
                f"{out}: steps {result.start_step} -> {result.step} of {total_steps(cfg)}, "
                f"loss {result.loss:.5g}, {result.seconds:.0f} s of training"
            )
            if result.stopped_at_time_budget:
                print(f"{out}: stopped at the time budget after step {result.step} (continue with --resume)")
            if result.peak_gpu_memory_bytes is not None:
                print(f"{out}: peak GPU memory {result.peak_gpu_memory_bytes / 2**30:.2f} GiB (PyTorch allocations)")
    return 0
