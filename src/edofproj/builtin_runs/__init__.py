"""Built-in runs: trained designs shipped inside the package, named wherever a run directory is.

``builtin:NAME`` stands for the run directory ``edofproj/builtin_runs/NAME/`` of the installed
package, with the layout of any training run (``config.yaml``, ``doe.npz``,
``checkpoints/last.pt``, ``train_log.csv``) and a model card ``MODEL.md`` (how it was trained,
what it scores). Its checkpoint holds the DOE and the network only (no optimizer state), so it
can be evaluated, exported, fine-tuned and used for compensation, not resumed.

    edofproj evaluate builtin:cpu-doe-net --out runs/ref-eval
    edofproj demo --pretrained              # the demo starts from it instead of training doe+net

A built-in run lives inside the package: commands that would write into a run directory ask for
``--out`` instead (:func:`require_output_outside`).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import EdofprojError
from ..fileio import atomic_path

PREFIX = "builtin:"
ROOT = Path(__file__).resolve().parent

#: The built-in runs and what each is.
BUILTIN_RUNS: dict[str, str] = {
    "cpu-doe-net": "the reference model: the cpu preset's DOE trained jointly with a U-Net for 10,000 steps, then "
    "the real-time multi-rate network (2x2 blocks, widths 16-16) trained for it, 6,800 steps of batch 16",
    "cpu-doe-unet": "the reference model until 2026-11-29: the cpu preset's DOE and a U-Net (behind its display "
    "guard) trained jointly for 10,000 steps",
    "cpu-doe-realtime": "cpu-doe-unet's DOE with the real-time multi-rate network (2x2 blocks, widths 16-16) "
    "trained for 6,800 steps of batch 16: within 0.002 SSIM of cpu-doe-unet at a fifth of its cost per frame",
    "demo-axicon-net": "the axicon+net baseline of `demo --pretrained`: the axicon with the reference model's "
    "real-time network, trained as its refit phase (600 steps of batch 16)",
    "demo-cubic-net": "the cubic+net baseline of `demo --pretrained`: the cubic plate with the reference model's "
    "real-time network, trained as its refit phase (600 steps of batch 16)",
    "demo-lens-onlineprodeb": "the demo's lens+onlineprodeb baseline (the OnlineProDeb re-implementation), 1,800 steps",
    "demo-refit-axicon-net": "the demo's axicon+net baseline: the axicon with the cpu preset's U-Net, trained as "
    "its refit phase (1,000 steps)",
    "demo-refit-cubic-net": "the demo's cubic+net baseline: the cubic plate with the cpu preset's U-Net, trained as "
    "its refit phase (1,000 steps)",
    "demo-realtime-axicon-net": "the axicon+net baseline of `demo --config cpu-realtime`: the axicon with the "
    "real-time multi-rate network, 2,400 steps",
    "demo-realtime-cubic-net": "the cubic+net baseline of `demo --config cpu-realtime`: the cubic plate with the "
    "real-time multi-rate network, 2,400 steps",
    "demo-realtime-lens-onlineprodeb": "the lens+onlineprodeb baseline of `demo --config cpu-realtime` (its PSFs "
    "in float32), 1,800 steps",
}

#: Checkpoint entries a built-in run keeps (what loading a trained run reads).
KEPT_CHECKPOINT_KEYS = ("format", "step", "elapsed_seconds", "doe", "net", "config")


def builtin_names() -> list[str]:
    """``builtin:NAME`` of every built-in run."""
    return [PREFIX + name for name in BUILTIN_RUNS]


def builtin_run_dir(name: str) -> Path:
    """The packaged directory of ``builtin:NAME`` (or of ``NAME``); a one-line error naming the
    built-in runs when there is no such run or its files are missing from the installation."""
    key = name[len(PREFIX) :] if name.startswith(PREFIX) else name
    if key not in BUILTIN_RUNS:
        raise EdofprojError(f"no built-in run '{PREFIX}{key}': the built-in runs are {', '.join(builtin_names())}")
    path = ROOT / key
    if not (path / "config.yaml").is_file():
        raise EdofprojError(
            f"the built-in run '{PREFIX}{key}' is missing from this installation ({path}): reinstall edofproj"
        )
    return path


def resolve_run_dir(run: str | Path) -> Path:
    """A run directory given as a path, or ``builtin:NAME`` (:func:`builtin_run_dir`)."""
    text = str(run)
    return builtin_run_dir(text) if text.startswith(PREFIX) else Path(run)


def is_builtin_run_dir(path: str | Path) -> bool:
    """Whether ``path`` is (inside) a built-in run's packaged directory."""
    try:
        return Path(path).resolve().is_relative_to(ROOT)
    except OSError:
        return False


def run_label(path: str | Path) -> str:
    """How outputs name a run or a file of it: ``builtin:NAME`` (``builtin:NAME/FILE``) for a
    built-in run's packaged directory (never the installation's path), any other path as given."""
    try:
        relative = Path(path).resolve().relative_to(ROOT)
    except (OSError, ValueError):
        return str(path)
    if not relative.parts or relative.parts[0] not in BUILTIN_RUNS:
        return str(path)
    return PREFIX + "/".join(relative.parts)


def require_output_outside(run_dir: str | Path, option: str = "--out") -> None:
    """Refuse to write into a built-in run (it belongs to the installed package)."""
    if is_builtin_run_dir(run_dir):
        raise EdofprojError(f"'{run_dir}' is a built-in run inside the installed package: give {option}")


def slim_checkpoint(source: str | Path, target: str | Path) -> Path:
    """Write a copy of the training checkpoint ``source`` that keeps only
    :data:`KEPT_CHECKPOINT_KEYS` (no optimizer, schedule or random state), atomically."""
    import torch

    state = torch.load(source, map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or "net" not in state:
        raise EdofprojError(f"'{source}' is not an edofproj training checkpoint")
    slim = {key: state[key] for key in KEPT_CHECKPOINT_KEYS if key in state}
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(target) as tmp:
        torch.save(slim, tmp)
    return target


def package_run(run_dir: str | Path, name: str, log_every: int = 10) -> Path:
    """Copy the trained run ``run_dir`` into the package as ``builtin:NAME`` (a maintainer's step):
    ``config.yaml``, ``doe.npz`` and ``validation_log.csv`` (when the run validated) as they are, ``checkpoints/last.pt`` slimmed
    (:func:`slim_checkpoint`), and every ``log_every``-th row of ``train_log.csv`` (plus the last).
    The model card ``MODEL.md`` is written by hand. Returns the packaged directory."""
    import shutil

    source = Path(run_dir)
    target = ROOT / name
    for required in ("config.yaml", "checkpoints/last.pt"):
        if not (source / required).is_file():
            raise EdofprojError(f"'{source}' has no {required}: not a trained run")
    target.mkdir(parents=True, exist_ok=True)
    for file_name in ("config.yaml", "doe.npz", "validation_log.csv"):
        if (source / file_name).is_file():
            with atomic_path(target / file_name) as tmp:
                shutil.copyfile(source / file_name, tmp)
    slim_checkpoint(source / "checkpoints/last.pt", target / "checkpoints/last.pt")
    log = source / "train_log.csv"
    if log.is_file():
        header, *rows = log.read_text(encoding="utf-8").splitlines()
        kept = [row for i, row in enumerate(rows, start=1) if i % log_every == 0 or i == len(rows)]
        with atomic_path(target / "train_log.csv") as tmp:
            tmp.write_text("\n".join([header, *kept]) + "\n", encoding="utf-8")
    return target
