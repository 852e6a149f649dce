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
copy ``checkpoints/last.pt``; only the newest ``keep`` step files are kept.
"""

from __future__ import annotations

import random
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import EdofprojError
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
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a bad file for the user
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EdofprojError(f"cannot read checkpoint '{path}': {first_line}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise EdofprojError(f"'{path}' is not an edofproj training checkpoint")
    return state
