"""Training sources: ``sample(batch_size, crop, generator) -> (B, 3, crop, crop)`` float32 in ``[0, 1]``.

A sample depends on nothing but the generator, so a resumed or data-parallel run draws the same
crops (:mod:`edofproj.training.sampling`). ``data.source``: ``builtin`` photographs, an image
``folder`` (:mod:`.photos`) or ``dead-leaves`` (:mod:`.dead_leaves`); ``data.dead_leaves_fraction``
mixes dead leaves into photographs (:class:`MixedSource`).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..errors import EdofprojError
from .dead_leaves import DeadLeavesSource, natural_color_palette
from .photos import FolderSource, PhotoSource, builtin_photo_source, find_image_files, folder_split


class MixedSource:
    """Photographs mixed with dead leaves: each sample of a batch is a dead-leaves image with
    probability ``dead_leaves_fraction`` (one Bernoulli draw per sample from the generator),
    else a photo crop. Dead leaves add edges of every scale and contrast that a handful of
    photographs lack; the photographs keep natural textures in the mix."""

    def __init__(self, photos, leaves: DeadLeavesSource, dead_leaves_fraction: float, seed: int = 0):
        self.photos = photos
        self.leaves = leaves
        self.dead_leaves_fraction = float(dead_leaves_fraction)
        self.crop = photos.crop
        self.generator = torch.Generator().manual_seed(int(seed))

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        generator = generator or self.generator
        is_leaves = (torch.rand(int(batch_size), generator=generator) < self.dead_leaves_fraction).tolist()
        return torch.cat([(self.leaves if leaves else self.photos).sample(1, crop, generator) for leaves in is_leaves])


# --------------------------------------------------------------------------- public API


def build_training_source(data_cfg, seed: int = 0):
    """The training source of a :class:`~edofproj.config.DataConfig`: an object with
    ``sample(batch_size, crop=None, generator=None) -> (B, 3, crop, crop)``. Without a
    generator, ``sample`` draws from the source's own generator seeded with ``seed``.
    ``data.dead_leaves_fraction > 0`` mixes dead leaves into a photo source (:class:`MixedSource`)."""
    if data_cfg.source == "dead-leaves" or data_cfg.dead_leaves_fraction > 0:
        leaves = DeadLeavesSource(
            data_cfg.crop,
            data_cfg.dead_leaves_min_radius_px,
            data_cfg.dead_leaves_max_radius_px,
            natural_color_palette(data_cfg.test_fraction),
            seed,
        )
        if data_cfg.source == "dead-leaves":
            return leaves
    photos: PhotoSource | FolderSource
    if data_cfg.source == "builtin":
        photos = builtin_photo_source(data_cfg.crop, data_cfg.test_fraction, seed)
    elif data_cfg.source == "folder":
        root = Path(data_cfg.folder)
        train = find_image_files(root) if data_cfg.test_folder else folder_split(root, data_cfg.test_fraction)[0]
        photos = FolderSource(train, data_cfg.crop, seed, root=root)
    else:
        raise EdofprojError(f"data.source={data_cfg.source!r} is not one of builtin, dead-leaves, folder")
    if data_cfg.dead_leaves_fraction > 0:
        return MixedSource(photos, leaves, data_cfg.dead_leaves_fraction, seed)
    return photos
