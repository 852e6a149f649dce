"""Training sources: ``sample(batch_size, crop, generator) -> (B, 3, crop, crop)`` float32 in ``[0, 1]``.

A sample depends on nothing but the generator, so a resumed or data-parallel run draws the same
crops (:mod:`edofproj.training.sampling`). ``data.source``: ``builtin`` photographs, an image
``folder`` (:mod:`.photos`), ``dead-leaves`` (:mod:`.dead_leaves`) or ``procedural``
(:mod:`.procedural`); ``data.dead_leaves_fraction`` and ``data.procedural_fraction`` mix those
synthetic images into photographs (:class:`MixedSource`).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..errors import EdofprojError
from .colour import ColourAugmentedSource
from .dead_leaves import DeadLeavesSource, natural_color_palette
from .photos import (
    BUILTIN_PHOTOS,
    FolderSource,
    PhotoSource,
    builtin_photo_source,
    builtin_split,
    find_image_files,
    folder_split,
    load_builtin_photo,
    probe_image_size,
)
from .procedural import ProceduralSource


class MixedSource:
    """Photographs mixed with synthetic images: for each sample of a batch one uniform draw ``u``
    from the generator picks a dead-leaves image when ``u < f_dl`` (``dead_leaves_fraction``), a
    procedural one when ``f_dl <= u < f_dl + f_proc`` (``procedural_fraction``), else a photo crop.
    Synthetic images add edges, gradients and textures of every scale and contrast that a handful
    of photographs lack; the photographs keep natural content in the mix."""

    def __init__(
        self,
        photos,
        leaves: DeadLeavesSource | None,
        dead_leaves_fraction: float,
        seed: int = 0,
        procedural: ProceduralSource | None = None,
        procedural_fraction: float = 0.0,
    ):
        self.photos = photos
        self.leaves = leaves
        self.procedural = procedural
        self.dead_leaves_fraction = float(dead_leaves_fraction) if leaves is not None else 0.0
        self.procedural_fraction = float(procedural_fraction) if procedural is not None else 0.0
        self.crop = photos.crop
        self.generator = torch.Generator().manual_seed(int(seed))

    def _source_for(self, u: float):
        if u < self.dead_leaves_fraction:
            return self.leaves
        if u < self.dead_leaves_fraction + self.procedural_fraction:
            return self.procedural
        return self.photos

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        generator = generator or self.generator
        draws = torch.rand(int(batch_size), generator=generator).tolist()
        return torch.cat([self._source_for(u).sample(1, crop, generator) for u in draws])


# --------------------------------------------------------------------------- public API


def build_training_source(data_cfg, seed: int = 0):
    """The training source of a :class:`~edofproj.config.DataConfig` (:func:`_build_source`), with
    ``data.colour_augment > 0`` that share of its samples colour-transformed
    (:class:`~edofproj.data.colour.ColourAugmentedSource`)."""
    source = _build_source(data_cfg, seed)
    share = float(getattr(data_cfg, "colour_augment", 0.0))
    gratings = bool(getattr(data_cfg, "colour_gratings", False))
    return ColourAugmentedSource(source, share, gratings) if share > 0 else source


def _build_source(data_cfg, seed: int = 0):
    """The training source of a :class:`~edofproj.config.DataConfig`: an object with
    ``sample(batch_size, crop=None, generator=None) -> (B, 3, crop, crop)``. Without a
    generator, ``sample`` draws from the source's own generator seeded with ``seed``.
    ``data.dead_leaves_fraction > 0`` or ``data.procedural_fraction > 0`` mixes synthetic images
    into a photo source (:class:`MixedSource`)."""
    procedural_fraction = float(getattr(data_cfg, "procedural_fraction", 0.0))
    radii = (data_cfg.dead_leaves_min_radius_px, data_cfg.dead_leaves_max_radius_px)
    leaves = procedural = None
    if data_cfg.source == "dead-leaves" or data_cfg.dead_leaves_fraction > 0:
        leaves = DeadLeavesSource(data_cfg.crop, *radii, natural_color_palette(data_cfg.test_fraction), seed)
        if data_cfg.source == "dead-leaves":
            return leaves
    if data_cfg.source == "procedural" or procedural_fraction > 0:
        procedural = ProceduralSource(data_cfg.crop, *radii, natural_color_palette(data_cfg.test_fraction), seed)
        if data_cfg.source == "procedural":
            return procedural
    photos: PhotoSource | FolderSource
    if data_cfg.source == "builtin":
        photos = builtin_photo_source(data_cfg.crop, data_cfg.test_fraction, seed)
    elif data_cfg.source == "folder":
        root = Path(data_cfg.folder)
        train = find_image_files(root) if data_cfg.test_folder else folder_split(root, data_cfg.test_fraction)[0]
        photos = FolderSource(train, data_cfg.crop, seed, root=root)
    else:
        raise EdofprojError(f"data.source={data_cfg.source!r} is not one of builtin, dead-leaves, folder, procedural")
    if leaves is not None or procedural is not None:
        return MixedSource(photos, leaves, data_cfg.dead_leaves_fraction, seed, procedural, procedural_fraction)
    return photos


def describe_training_data(data_cfg) -> str:
    """One line saying what a run trains and tests on: the images found, how many train and how
    many are held out (and by which rule), and how many training images are too small for the
    crop or unreadable (those are skipped, with one warning each when the source is built)."""
    synthetic = {"dead-leaves": "dead-leaves images", "procedural": "procedural images"}
    mix = [
        f"{100 * fraction:g} % {name}"
        for fraction, name in (
            (data_cfg.dead_leaves_fraction, "dead leaves"),
            (float(getattr(data_cfg, "procedural_fraction", 0.0)), "procedural"),
        )
        if fraction > 0 and data_cfg.source in ("builtin", "folder")
    ]
    mixed = f"; mixed with {' and '.join(mix)} per sample" if mix else ""
    rule = f"data.test_fraction={data_cfg.test_fraction:g}, chosen by the SHA-256 of their names"
    if data_cfg.source in ("builtin", *synthetic):
        train_names, test_names = builtin_split(data_cfg.test_fraction)
        if data_cfg.source in synthetic:
            return (
                f"data: {synthetic[data_cfg.source]} drawn at random ({data_cfg.crop} px crops); tested on the "
                f"{len(test_names)} held-out built-in photographs ({rule})"
            )
        too_small = sum(min(load_builtin_photo(name).shape[:2]) < data_cfg.crop for name in train_names)
        return (
            f"data: {len(BUILTIN_PHOTOS)} built-in photographs: {len(train_names)} for training, {len(test_names)} "
            f"held out for testing ({rule}){_skipped(too_small, data_cfg.crop)}{mixed}"
        )
    root = Path(data_cfg.folder)
    if data_cfg.test_folder:
        train = find_image_files(root)
        test = find_image_files(data_cfg.test_folder)
        split = (
            f"{len(train)} images in '{root}': all for training; {len(test)} for testing in "
            f"data.test_folder '{data_cfg.test_folder}'"
        )
    else:
        train, test = folder_split(root, data_cfg.test_fraction)
        split = (
            f"{len(train) + len(test)} images in '{root}': {len(train)} for training, {len(test)} held out for "
            f"testing ({rule})"
        )
    small = 0
    for path in train:
        size = probe_image_size(path)
        small += size is None or min(size) < data_cfg.crop
    return f"data: {split}{_skipped(small, data_cfg.crop)}{mixed}"


def _skipped(count: int, crop: int) -> str:
    return f"; {count} training image(s) skipped (unreadable or smaller than the {crop} px crop)" if count else ""
