"""The run directory (its layout: :mod:`edofproj.runs`): new-run and resume checks, the saved
configuration, and loading a trained run for evaluation, export or fine-tuning."""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from torch import nn

from ..builtin_runs import PREFIX, resolve_run_dir
from ..compensation.registry import build_network
from ..config import Config, dump_config, load_config, to_dict
from ..doe import DOE, build_run_doe, load_doe
from ..errors import EdofprojError
from ..fileio import write_text_atomic
from ..locking import is_lock_file
from .checkpoint import LAST_NAME, load_newest_intact_checkpoint, load_state_checked

CONFIG_NAME = "config.yaml"
DOE_NAME = "doe.npz"
CHECKPOINT_DIR = "checkpoints"
FIGURES_DIR = "figures"

#: Keys that may change when a run is resumed (they do not change what is computed so far).
RESUMABLE_KEYS = (
    "train.steps",
    "train.refit_steps",
    "train.checkpoint_every",
    "train.keep_checkpoints",
    "train.threads",
    "train.device",
    "name",
)


#: Config keys that hold a file or folder path: a run's ``config.yaml`` stores them absolute, so
#: the run can be resumed, evaluated or fine-tuned from any working directory.
PATH_KEYS = (
    "optics.wavefront_map",
    "optics.aberration_csv",
    "optics.lens_prescription",
    "spectrum.spd_csv",
    "doe.path",
    "loss.weights_dir",
    "data.folder",
    "data.test_folder",
    "train.teacher",
)


def with_absolute_paths(cfg: Config, base: str | Path | None = None) -> Config:
    """A copy of ``cfg`` whose relative paths (:data:`PATH_KEYS`) are made absolute against
    ``base`` (default: the working directory); ``builtin:NAME`` and absolute paths stay as they are."""
    cfg = copy.deepcopy(cfg)
    root = Path(base) if base is not None else Path.cwd()
    for key in PATH_KEYS:
        section_name, name = key.split(".")
        section = getattr(cfg, section_name)
        value = getattr(section, name)
        if value and not str(value).startswith(PREFIX) and not Path(value).is_absolute():
            setattr(section, name, str((root / Path(value).expanduser()).resolve()))
    return cfg


def run_inputs(run_dir: str | Path | None, what: str = "RUN") -> list[tuple[str, Path]]:
    """The files and folders of a run that the commands read -- its ``config.yaml``, ``doe.npz`` and
    ``checkpoints/`` -- named for messages (``RUN's doe.npz``): the inputs that no output may replace
    (:func:`edofproj.outputs.refuse_output_over_inputs`; the run directory itself is their holder).
    Empty for None."""
    if run_dir is None:
        return []
    run = Path(run_dir)
    return [(f"{what}'s {name}", run / name) for name in (CONFIG_NAME, DOE_NAME, CHECKPOINT_DIR)]


def last_checkpoint_path(run_dir: str | Path) -> Path:
    return resolve_run_dir(run_dir) / CHECKPOINT_DIR / LAST_NAME


# ----------------------------------------------------------------------------- starting / resuming


def check_new_run_dir(run_dir: str | Path, hint: str = "use --resume to continue that run, or another --out") -> None:
    """Refuse to start a fresh run in a directory that already holds files (its lock file aside);
    ``hint`` says what to do instead."""
    path = Path(run_dir)
    if path.exists() and not path.is_dir():
        raise EdofprojError(f"--out '{path}' exists and is not a directory")
    if path.is_dir() and any(not is_lock_file(p) for p in path.iterdir()):
        raise EdofprojError(f"--out '{path}' is not empty: {hint}")


def saved_config(run_dir: str | Path, overrides=()) -> Config:
    """The ``config.yaml`` of a run (plus ``section.key=value`` overrides)."""
    path = resolve_run_dir(run_dir) / CONFIG_NAME
    if not path.is_file():
        raise EdofprojError(f"'{run_dir}' is not a training run (no {CONFIG_NAME})")
    return load_config(str(path), overrides)


def flatten_keys(data: dict, prefix: str = "") -> dict:
    """``{"section.key": value}`` of a nested configuration dictionary (:func:`~edofproj.config.to_dict`)."""
    flat = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(flatten_keys(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def check_resume_config(run_dir: str | Path, cfg: Config) -> None:
    """Refuse to resume with a configuration that changes what the run computes."""
    old = flatten_keys(to_dict(with_absolute_paths(saved_config(run_dir))))  # a run saved before paths were absolute
    new = flatten_keys(to_dict(with_absolute_paths(cfg)))
    changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k) and k not in RESUMABLE_KEYS)
    if changed:
        shown = ", ".join(f"{k} ({old.get(k)!r} -> {new.get(k)!r})" for k in changed[:3])
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        raise EdofprojError(
            f"--resume: the config differs from {Path(run_dir) / CONFIG_NAME} in {shown}{more}; "
            f"only {', '.join(RESUMABLE_KEYS)} may change"
        )


def write_run_config(run_dir: str | Path, cfg: Config) -> None:
    """Write ``config.yaml`` with its paths absolute (:func:`with_absolute_paths`)."""
    write_text_atomic(Path(run_dir) / CONFIG_NAME, dump_config(with_absolute_paths(cfg)))


# ----------------------------------------------------------------------------- loading a finished run


@dataclass
class TrainedRun:
    """A trained run: its configuration, fabricated DOE, compensation network (eval mode). ``cfg.net``
    is the loaded network's section: ``config.yaml``'s ``refit_net`` once the run's refit phase has
    begun (:meth:`~edofproj.config.Config.network_at`), else its ``net``."""

    cfg: Config
    doe: DOE
    net: nn.Module
    run_dir: Path
    step: int


def load_run(run_dir: str | Path, map_location="cpu") -> TrainedRun:
    """Load ``config.yaml``, the DOE and the network of the newest checkpoint of a run
    (a directory, or a built-in run ``builtin:NAME``: :mod:`edofproj.builtin_runs`).

    The DOE is the fabricated design in ``doe.npz`` when present (what a mask would make);
    otherwise (a lens-only run, or a run without a finished checkpoint of its DOE) it is
    rebuilt from the configuration and the checkpoint.
    """
    run_dir = resolve_run_dir(run_dir)
    if not run_dir.is_dir():
        raise EdofprojError(f"run directory '{run_dir}' does not exist")
    cfg = saved_config(run_dir)
    checkpoint, checkpoint_path = load_newest_intact_checkpoint(run_dir / CHECKPOINT_DIR, map_location=map_location)
    cfg = dataclasses.replace(cfg, net=cfg.network_at(int(checkpoint["step"])))
    net = build_network(cfg.net)
    load_state_checked(net, checkpoint["net"], f"the checkpoint '{checkpoint_path}'")
    net.eval()
    doe_file = run_dir / DOE_NAME
    if doe_file.is_file():
        doe = load_doe(doe_file)
    else:
        doe = build_run_doe(cfg)
        if checkpoint.get("doe"):
            load_state_checked(doe, checkpoint["doe"], f"the DOE of checkpoint '{checkpoint_path}'")
    doe.eval()
    return TrainedRun(cfg=cfg, doe=doe, net=net, run_dir=run_dir, step=int(checkpoint["step"]))
