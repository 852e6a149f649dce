"""Option helpers shared by the subcommands."""

from __future__ import annotations

import argparse
from typing import Any, Sequence

import numpy as np

from ..builtin_runs import resolve_run_dir
from ..config import Config, load_config
from ..errors import EdofprojError


def add_config_options(parser: argparse.ArgumentParser) -> None:
    """``--config FILE|PRESET`` and repeatable ``--set section.key=value``."""
    parser.add_argument(
        "--config", default=None, help="YAML config file or preset name (cpu, cpu-realtime, paper, realtime)"
    )
    add_set_option(parser)


def add_set_option(
    parser: argparse.ArgumentParser, help: str = "override a config key, e.g. --set train.steps=100 (repeatable)"
) -> None:
    """The repeatable ``--set section.key=value`` (into ``args.overrides``)."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=help)


def run_directory(text: str) -> str:
    """``type=`` of a RUN argument: a run directory, or a built-in run ``builtin:NAME`` (its
    packaged directory; :mod:`edofproj.builtin_runs`)."""
    try:
        return str(resolve_run_dir(text))
    except EdofprojError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


RUN_HELP_SUFFIX = " or a built-in run (builtin:cpu-doe-net)"


def add_method_options(parser: argparse.ArgumentParser, blind_only: bool = False) -> None:
    """``--method NAME`` (default: the run's own network, as ``evaluate`` scores it) and ``--baselines DIR``."""
    from ..methods.catalogue import METHOD_NAMES, OURS  # no torch: the catalogue is plain data

    parser.add_argument(
        "--method",
        default=OURS,
        choices=METHOD_NAMES,
        metavar="NAME",
        help=f"the compensation method, exactly as 'edofproj evaluate' scores it (default: {OURS}, the run's own "
        "network, behind its display guard where the run has one); "
        + ("a blind one of: " if blind_only else "one of: ")
        + ", ".join(METHOD_NAMES),
    )
    parser.add_argument(
        "--baselines",
        default=None,
        metavar="DIR",
        help="where the separate runs of the baseline networks are (lens_net, cubic_net, ...; default: the run's "
        "parent directory)",
    )


def add_device_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--device {auto,cpu,cuda}`` (default cpu): where ``what`` runs (auto: the GPU when available)."""
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="cpu",
        help=f"{what}: on the CPU (default) or a CUDA GPU (auto: the GPU when available)",
    )


def add_design_source_argument(parser: argparse.ArgumentParser) -> None:
    """The positional ``RUN|DESIGN_FILE`` (into ``args.source``): a run directory holding ``doe.npz``,
    a built-in run, or a DOE ``.npz`` file."""
    parser.add_argument(
        "source",
        metavar="RUN|DESIGN_FILE",
        type=run_directory,
        help="run directory with doe.npz" + RUN_HELP_SUFFIX + ", or a DOE .npz file",
    )


def config_from_args(args: argparse.Namespace, extra_overrides=()) -> Config:
    return load_config(args.config, list(extra_overrides) + list(getattr(args, "overrides", []) or []))


#: Most values a ``start:stop:step`` range may give (a depth sweep of 0.05 mm steps over 300-800 mm).
MAX_RANGE_VALUES = 10_000


def parse_number_list(text: str, what: str) -> list[float]:
    """``"300,350,400"`` or a range ``"300:800:50"`` (start:stop:step, stop included; at most
    :data:`MAX_RANGE_VALUES` values, counted before any is made)."""
    values: list[float] = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if ":" in part:
                pieces = [float(p) for p in part.split(":")]
                if len(pieces) != 3 or pieces[2] <= 0:
                    raise ValueError
                start, stop, step = pieces
                if not all(np.isfinite(pieces)):
                    raise ValueError
                if stop < start:
                    raise EdofprojError(
                        f"{what} '{part}' runs down from {start:g} to {stop:g}: a range is start:stop:step with "
                        f"start <= stop, e.g. {stop:g}:{start:g}:{step:g}"
                    )
                n = int(np.floor((stop - start) / step + 1e-9)) + 1
                if n > MAX_RANGE_VALUES:
                    raise EdofprojError(
                        f"{what} '{part}' gives {n} values, more than {MAX_RANGE_VALUES}: use a larger step"
                    )
                values += list(start + step * np.arange(max(n, 0)))
            else:
                values.append(float(part))
        except ValueError:
            raise EdofprojError(f"{what} '{text}' must be numbers separated by commas, or start:stop:step") from None
    if not values:
        raise EdofprojError(f"{what} is empty")
    if not all(np.isfinite(values)):
        raise EdofprojError(f"{what} '{text}' must be finite numbers")
    return values


def parse_name_list(text: str) -> list[str]:
    return [p.strip() for p in str(text).split(",") if p.strip()]


def refuse_output_over(
    output: str | None,
    option: str,
    inputs: Sequence[tuple[str, str | None]] = (),
    runs: Sequence[tuple[str, str | None]] = (),
    file_output: bool = False,
) -> None:
    """:func:`edofproj.outputs.refuse_output_over_inputs` for a command's options: ``output`` (the
    option ``option``) is none of ``inputs`` (``(option, path)``; a path None or of nothing on disk is
    skipped), contains none, lies inside none; ``runs`` are ``(option, path)`` of run directories
    (the holder of their files, :func:`edofproj.runs.run_inputs`) or design files; ``file_output``:
    ``output`` is one file (it may lie inside an input folder)."""
    from pathlib import Path

    from ..outputs import refuse_output_over_inputs

    if output is None:
        return
    named: list[tuple[str, Any]] = list(inputs)
    holders = []
    for what, path in runs:
        if path is not None and Path(path).is_dir():
            from ..runs import run_inputs  # start-up: torch

            holders.append((what, path))
            named += run_inputs(path, what)
        else:
            named.append((what, path))
    refuse_output_over_inputs(output, named, option, holders=holders, file_output=file_output)
