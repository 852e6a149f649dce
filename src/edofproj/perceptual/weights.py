"""Where the pretrained weights of the perceptual metrics come from.

Nothing is downloaded. Two kinds of files are needed:

* **ImageNet backbones** in torchvision's format (``vgg16-397923af.pth``,
  ``alexnet-owt-7be5be79.pth``). Searched in ``weights_dir`` (when given), then in torch's hub
  cache ``torch.hub.get_dir()/checkpoints`` (``$TORCH_HOME/hub/checkpoints``, by default
  ``~/.cache/torch/hub/checkpoints``), which is where torchvision downloads them.
* **Metric-specific weights**: the DISTS ``alpha``/``beta`` channel weights and the LPIPS
  linear layers. torchmetrics (>= 1.x) ships both as package data
  (``functional/image/dists_models/weights.pt``, ``functional/image/lpips_models/{alex,vgg}.pth``);
  they are read directly from its installation folder, without importing torchmetrics'
  image modules (those import torchvision). A copy in ``weights_dir`` (``dists_weights.pt``,
  ``lpips_alex.pth``, ``lpips_vgg.pth``) takes precedence.

A missing file raises :class:`PerceptualWeightsMissing` naming the file, where to put it and
how to get it, so callers can report the metric as unavailable.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Optional

import torch

from ..errors import EdofprojError


class PerceptualWeightsMissing(EdofprojError):
    """A pretrained weight file needed by DISTS or LPIPS is not on this machine."""


#: torchvision's file names for the ImageNet weights (as stored in the torch hub cache).
TORCHVISION_WEIGHT_FILES = {
    "vgg16": "vgg16-397923af.pth",
    "alexnet": "alexnet-owt-7be5be79.pth",
}

#: torchmetrics package data (paths relative to the torchmetrics package folder) and the
#: name under which a copy may be placed in ``weights_dir``.
TORCHMETRICS_DATA_FILES = {
    "dists": ("functional/image/dists_models/weights.pt", "dists_weights.pt"),
    "lpips-alex": ("functional/image/lpips_models/alex.pth", "lpips_alex.pth"),
    "lpips-vgg": ("functional/image/lpips_models/vgg.pth", "lpips_vgg.pth"),
}

PathLike = str | os.PathLike


def hub_checkpoint_dir() -> Path:
    """torch's hub cache for weight files: ``torch.hub.get_dir()/checkpoints``."""
    return Path(torch.hub.get_dir()) / "checkpoints"


def _torchmetrics_dir() -> Optional[Path]:
    """The installation folder of torchmetrics, found without importing it (None if absent)."""
    spec = importlib.util.find_spec("torchmetrics")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def backbone_weights_path(backbone: str, weights_dir: Optional[PathLike] = None) -> Path:
    """Path of torchvision's ImageNet weight file for ``backbone`` (``vgg16`` or ``alexnet``).

    Raises :class:`PerceptualWeightsMissing` when neither ``weights_dir`` nor the hub cache
    holds it.
    """
    if backbone not in TORCHVISION_WEIGHT_FILES:
        raise EdofprojError(f"unknown backbone '{backbone}' (allowed: {', '.join(TORCHVISION_WEIGHT_FILES)})")
    name = TORCHVISION_WEIGHT_FILES[backbone]
    folders = ([Path(weights_dir)] if weights_dir is not None else []) + [hub_checkpoint_dir()]
    for folder in folders:
        if (folder / name).is_file():
            return folder / name
    where = " or ".join(f"'{folder}'" for folder in folders)
    raise PerceptualWeightsMissing(
        f"missing ImageNet weights '{name}': put it in {where} (on a machine with internet, "
        f"python -c \"import torchvision; torchvision.models.{backbone}(weights='DEFAULT')\" "
        f"downloads it to {hub_checkpoint_dir()})"
    )


def metric_weights_path(metric: str, weights_dir: Optional[PathLike] = None) -> Path:
    """Path of the metric's own weights (``dists``, ``lpips-alex``, ``lpips-vgg``).

    ``weights_dir/<copy name>`` first, then torchmetrics' package data. Raises
    :class:`PerceptualWeightsMissing` when neither exists.
    """
    if metric not in TORCHMETRICS_DATA_FILES:
        raise EdofprojError(f"unknown perceptual metric '{metric}' (allowed: {', '.join(TORCHMETRICS_DATA_FILES)})")
    package_path, copy_name = TORCHMETRICS_DATA_FILES[metric]
    candidates = [Path(weights_dir) / copy_name] if weights_dir is not None else []
    package_dir = _torchmetrics_dir()
    if package_dir is not None:
        candidates.append(package_dir / package_path)
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    where = f"'{Path(weights_dir) / copy_name}' or " if weights_dir is not None else ""
    raise PerceptualWeightsMissing(
        f"missing {metric} weights: need {where}torchmetrics' package file '{package_path}' "
        f"(pip install 'torchmetrics>=1.0', or copy that file to <weights_dir>/{copy_name})"
    )


def load_state_dict_file(path: PathLike) -> dict:
    """``torch.load`` a tensor-only state dict on the CPU; unreadable files raise EdofprojError."""
    try:
        state = torch.load(Path(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a bad file
        raise EdofprojError(f"cannot read weight file '{path}': {exc}".splitlines()[0]) from None
    if not isinstance(state, dict):
        raise EdofprojError(f"weight file '{path}' does not hold a state dict")
    return state
