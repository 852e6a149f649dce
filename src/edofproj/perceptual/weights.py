"""Where the pretrained weights of the perceptual metrics come from, and how to fetch them.

Nothing is downloaded implicitly. Two kinds of files are needed:

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

**Fetching the backbones** (``edofproj weights fetch``, :func:`fetch_backbone_weights`): each file
of :data:`BACKBONE_DOWNLOADS` is streamed from PyTorch's download server into a temporary file
beside its destination (default: the hub cache, where :func:`backbone_weights_path` looks), its
SHA-256 is computed on the way and compared with the published one, and only a matching file is
renamed into place. A checksum mismatch or an interrupted download leaves nothing behind. A file
already present with the right checksum is kept.
"""

from __future__ import annotations

import hashlib
import http.client
import importlib.util
import os
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import torch

from ..errors import EdofprojError
from ..fileio import TEMP_PATTERN, atomic_path
from ..locking import directory_lock


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

#: Where torchvision publishes its ImageNet weights (``<base>/<file name>``).
TORCHVISION_DOWNLOAD_BASE = "https://download.pytorch.org/models"


@dataclass(frozen=True)
class WeightDownload:
    """One published weight file: its name and full SHA-256 (torchvision's file names carry the
    first 8 hex digits of it)."""

    backbone: str
    filename: str
    sha256: str


#: The backbone files LPIPS (alexnet, vgg16) and DISTS (vgg16) read, with their published SHA-256.
BACKBONE_DOWNLOADS = {
    "vgg16": WeightDownload(
        "vgg16", TORCHVISION_WEIGHT_FILES["vgg16"], "397923af8e79cdbb6a7127f12361acd7a2f83e06b05044ddf496e83de57a5bf0"
    ),
    "alexnet": WeightDownload(
        "alexnet",
        TORCHVISION_WEIGHT_FILES["alexnet"],
        "7be5be791159472b1fbf3c69796f7cb30dca7ad8466c2df70058c37116cdee02",
    ),
}

FETCH_COMMAND = "edofproj weights fetch"


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
        f"missing ImageNet weights '{name}': run `{FETCH_COMMAND} --backbone {backbone}` "
        f"(downloads it to {hub_checkpoint_dir()} and checks its SHA-256), or put it in {where}"
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


# --------------------------------------------------------------------------- fetching


def file_sha256(path: PathLike, chunk_bytes: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(chunk_bytes), b""):
            digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True)
class FetchResult:
    """What :func:`fetch_backbone_weights` did for one file: ``downloaded`` or ``present``."""

    backbone: str
    path: Path
    status: str
    sha256: str


def download_verified(
    url: str, target: PathLike, sha256: str, timeout_s: float = 60.0, chunk_bytes: int = 1 << 20
) -> Path:
    """Stream ``url`` into ``target`` only if its SHA-256 is ``sha256``.

    The bytes go to a temporary file beside ``target`` (:func:`edofproj.fileio.atomic_path`) and
    are hashed on the way; the file is renamed onto ``target`` only when the download completed
    (as many bytes as the server announced) and the digest matches. Otherwise the temporary file
    is removed, ``target`` is left as it was, and :class:`EdofprojError` says why.
    """
    target = Path(target)
    expected = sha256.lower()
    try:
        with atomic_path(target) as tmp:
            digest = hashlib.sha256()
            received = 0
            with urllib.request.urlopen(url, timeout=timeout_s) as response, open(tmp, "wb") as out:
                announced = response.headers.get("Content-Length")
                for chunk in iter(lambda: response.read(chunk_bytes), b""):
                    digest.update(chunk)
                    out.write(chunk)
                    received += len(chunk)
            if announced is not None and received != int(announced):
                raise EdofprojError(
                    f"download of {url} stopped after {received} of {announced} bytes; nothing was kept"
                )
            if digest.hexdigest() != expected:
                raise EdofprojError(
                    f"{url}: SHA-256 {digest.hexdigest()} is not the published {expected}; the file was not kept"
                )
    except (urllib.error.URLError, http.client.HTTPException, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", None) or exc
        raise EdofprojError(f"cannot download {url}: {reason}; nothing was kept".splitlines()[0]) from None
    return target


def fetch_backbone_weights(
    backbones: Sequence[str] = tuple(BACKBONE_DOWNLOADS),
    dest_dir: Optional[PathLike] = None,
    base_url: str = TORCHVISION_DOWNLOAD_BASE,
    progress: Optional[Callable[[str], None]] = None,
    timeout_s: float = 60.0,
) -> list[FetchResult]:
    """Download the ImageNet backbone files of ``backbones`` into ``dest_dir`` (default: the hub
    cache :func:`hub_checkpoint_dir`, where the metrics look) from ``<base_url>/<file name>``,
    each checked against its published SHA-256 (:func:`download_verified`). A file already there
    with the right digest is kept (status ``present``); one with another digest is replaced."""
    unknown = [b for b in backbones if b not in BACKBONE_DOWNLOADS]
    if unknown or not backbones:
        raise EdofprojError(
            f"unknown backbone(s) {', '.join(unknown) or '(none given)'} (allowed: {', '.join(BACKBONE_DOWNLOADS)})"
        )
    folder = Path(dest_dir) if dest_dir is not None else hub_checkpoint_dir()
    if folder.exists() and not folder.is_dir():
        raise EdofprojError(f"'{folder}' exists and is not a directory")
    say = progress or (lambda message: None)
    # one fetch per folder at a time; then the partial downloads of a killed fetch can go
    with directory_lock(folder, "edofproj weights fetch"):
        for stale in remove_partial_downloads(folder):
            say(f"removed the partial download {stale.name} of an interrupted fetch")
        return _fetch_locked(backbones, folder, base_url, say, timeout_s)


def remove_partial_downloads(folder: Path) -> list[Path]:
    """Delete the temporary files (:func:`edofproj.fileio.atomic_path` names) of the backbone files
    in ``folder`` that a killed fetch left; only those of :data:`BACKBONE_DOWNLOADS`' file names
    (the folder is shared with torch's hub cache). Call while holding the folder's lock."""
    names = {item.filename for item in BACKBONE_DOWNLOADS.values()}
    removed = []
    for path in folder.glob(".*"):
        match = TEMP_PATTERN.match(path.name)
        if match and match.group("target") in names and path.is_file() and not path.is_symlink():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def _fetch_locked(backbones, folder: Path, base_url: str, say, timeout_s: float) -> list[FetchResult]:
    results = []
    for backbone in dict.fromkeys(backbones):
        item = BACKBONE_DOWNLOADS[backbone]
        target = folder / item.filename
        if target.is_file():
            if file_sha256(target) == item.sha256:
                say(f"{item.filename}: already present with the published SHA-256 ({target})")
                results.append(FetchResult(backbone, target, "present", item.sha256))
                continue
            say(f"{item.filename}: the file at {target} has another SHA-256; downloading it again")
        url = f"{base_url.rstrip('/')}/{item.filename}"
        say(f"{item.filename}: downloading {url}")
        download_verified(url, target, item.sha256, timeout_s=timeout_s)
        say(f"{item.filename}: SHA-256 verified, saved to {target}")
        results.append(FetchResult(backbone, target, "downloaded", item.sha256))
    return results
