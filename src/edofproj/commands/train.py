"""``edofproj train``: jointly train the DOE and the compensation network (a run directory).

    edofproj train --config cpu --out runs/cpu [--set train.steps=800 ...] [--steps N] [--resume]
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
        print(describe_training_data(cfg.data), flush=True)
    result = train(cfg, out, resume=args.resume, stop_after=args.stop_after, progress=not args.quiet)
    if int(os.environ.get("RANK", "0")) == 0:
        if result.step == result.start_step:
            print(
                f"{out}: nothing to do, the run is at step {result.step} of {total_steps(cfg)} "
                f"(raise --steps to continue)"
            )
        else:
            print(
                f"{out}: steps {result.start_step} -> {result.step} of {total_steps(cfg)}, "
                f"loss {result.loss:.5g}, {result.seconds:.0f} s of training"
            )
            if result.peak_gpu_memory_bytes is not None:
                print(f"{out}: peak GPU memory {result.peak_gpu_memory_bytes / 2**30:.2f} GiB (PyTorch allocations)")
    return 0
