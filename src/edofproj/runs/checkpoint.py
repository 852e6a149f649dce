"""Training checkpoints: everything needed to continue a run exactly where it stopped.

A checkpoint (``torch.save`` of a plain dictionary, loadable with ``weights_only=True``) holds

* ``step``: optimizer steps completed, and ``elapsed_seconds`` of training so far;
* ``doe``, ``net``: the state dictionaries of the DOE and the compensation network;
* ``optimizer``, ``scheduler``: Adam's moments and the learning-rate schedule's position;
* ``rng``: the global random states of torch (and CUDA), NumPy and Python's ``random``.
  The training draws themselves (image crops, depths, camera noise) do not use global state:
  they come from generators seeded by ``(seed, step, sample index)``
  (:mod:`edofproj.training.sampling`), so the step counter *is* the data generator's state;
* ``config``: the resolved configuration, for reference.

Files are written atomically (temporary file + rename): ``checkpoints/step_XXXXXX.pt`` and a
copy ``checkpoints/last.pt``; only the newest ``keep`` step files are kept. When ``last.pt``
cannot be read, :func:`load_newest_intact_checkpoint` falls back to the newest step file that
can, and says so (a :class:`~edofproj.errors.RecoveryWarning`).
"""

from __future__ import annotations

import random
import re
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import EdofprojError, RecoveryWarning
from ..fileio import atomic_path

FORMAT = "edofproj-checkpoint-v1"
LAST_NAME = "last.pt"
STEP_PATTERN = re.compile(r"^step_(\d{6,})\.pt$")


def step_name(step: int) -> str:
    return f"step_{step:06d}.pt"


# ----------------------------------------------------------------------------- RNG state


def capture_rng_state() -> dict[str, Any]:
    """The global random states of torch, CUDA, NumPy and Python, as tensors and plain values."""
    np_state = np.random.get_state(legacy=True)
    if isinstance(np_state, dict):
        raise RuntimeError("NumPy's global random generator is not MT19937; its state cannot be checkpointed")
    np_kind, np_keys, np_pos, np_has_gauss, np_gauss = np_state
    state = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "kind": str(np_kind),
            "keys": torch.from_numpy(np_keys.astype(np.int64)),
            "pos": int(np_pos),
            "has_gauss": int(np_has_gauss),
            "cached_gaussian": float(np_gauss),
        },
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng_state(state: dict[str, Any]) -> None:
    """Inverse of :func:`capture_rng_state`."""
    torch.set_rng_state(state["torch"])
    np_state = state["numpy"]
    np.random.set_state(
        (
            np_state["kind"],
            np_state["keys"].numpy().astype(np.uint32),
            np_state["pos"],
            np_state["has_gauss"],
            np_state["cached_gaussian"],
        )
    )
    random.setstate(_as_tuples(state["python"]))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _as_tuples(value):
    """Python's random state is nested tuples; a round trip may turn them into lists."""
    if isinstance(value, (list, tuple)):
        return tuple(_as_tuples(v) for v in value)
    return value


# ----------------------------------------------------------------------------- files


def save_checkpoint(directory: str | Path, state: dict[str, Any], keep: int = 0) -> Path:
    """Write ``state`` (with ``state["step"]``) as ``step_XXXXXX.pt`` and ``last.pt`` atomically.

    ``keep > 0``: delete all but the newest ``keep`` step files afterwards. Returns the step file.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    payload = dict(state, format=FORMAT)
    step_file = directory / step_name(int(state["step"]))
    with atomic_path(step_file) as tmp:
        torch.save(payload, tmp)
    with atomic_path(directory / LAST_NAME) as tmp:
        shutil.copyfile(step_file, tmp)
    if keep > 0:
        for old in list_step_checkpoints(directory)[:-keep]:
            old.unlink(missing_ok=True)
    return step_file


def list_step_checkpoints(directory: str | Path) -> list[Path]:
    """The ``step_XXXXXX.pt`` files in ``directory``, oldest step first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    steps = {}
    for p in directory.iterdir():
        match = STEP_PATTERN.match(p.name)
        if match:
            steps[p] = int(match.group(1))
    return sorted(steps, key=steps.__getitem__)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (one-line error if missing or unreadable)."""
    path = Path(path)
    if not path.is_file():
        raise EdofprojError(f"no checkpoint at '{path}'")
    try:
        with warnings.catch_warnings():
            # a damaged file can look like a pickle of another protocol: torch warns before it fails, and the
            # failure below is the one line the user needs
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a bad file for the user
        # never repeat the library's advice (it suggests weights_only=False, which runs code from the file)
        size = path.stat().st_size
        raise EdofprojError(
            f"cannot read checkpoint '{path}' ({size} bytes, {type(exc).__name__}): it is truncated, damaged "
            "or not an edofproj checkpoint"
        ) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise EdofprojError(f"'{path}' is not an edofproj training checkpoint")
    return state


def load_newest_intact_checkpoint(
    directory: str | Path, map_location: str | torch.device = "cpu"
) -> tuple[dict[str, Any], Path]:
    """``(state, path)`` of ``directory/last.pt``, or, when that cannot be read, of the newest
    ``step_XXXXXX.pt`` that can (with a :class:`~edofproj.errors.RecoveryWarning` naming both).
    Raises the error about ``last.pt`` when no checkpoint can be read."""
    directory = Path(directory)
    last = directory / LAST_NAME
    try:
        return load_checkpoint(last, map_location), last
    except EdofprojError as first_error:
        candidates = list_step_checkpoints(directory)
        for candidate in reversed(candidates):
            try:
                state = load_checkpoint(candidate, map_location)
            except EdofprojError:
                continue
            problem = "is missing" if not last.is_file() else "cannot be read (truncated or damaged)"
            warnings.warn(
                f"'{last}' {problem}: using '{candidate.name}' (step {int(state['step'])}), "
                "the newest intact checkpoint",
                RecoveryWarning,
                stacklevel=2,
            )
            return state, candidate
        if candidates:
            raise EdofprojError(
                f"{first_error}, and none of the {len(candidates)} step_*.pt files beside it can be read either"
            ) from None
        raise first_error from None


def load_state_checked(module: torch.nn.Module, state: dict[str, Any], what: str) -> None:
    """``module.load_state_dict(state)``, or a one-line error saying what differs: missing and
    unexpected parameter names and the first shape mismatch (``what`` names the checkpoint)."""
    own = module.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    shapes = [
        f"{k} is {tuple(state[k].shape)} in the checkpoint but {tuple(own[k].shape)} in the network"
        for k in own
        if k in state and hasattr(state[k], "shape") and tuple(state[k].shape) != tuple(own[k].shape)
    ]
    problems = []
    if missing:
        problems.append(f"{len(missing)} parameter(s) missing from the checkpoint (e.g. {missing[0]})")
    if unexpected:
        problems.append(f"{len(unexpected)} unknown to the network (e.g. {unexpected[0]})")
    if shapes:
        problems.append(f"{len(shapes)} of different shape ({shapes[0]})")
    if not problems:
        try:
            module.load_state_dict(state)
            return
        except (RuntimeError, KeyError, ValueError) as exc:
            problems.append(type(exc).__name__)
    raise EdofprojError(
        f"{what} does not fit the {type(module).__name__} built from the config: {'; '.join(problems)}; "
        "the net.* settings must be those the checkpoint was trained with"
    )
