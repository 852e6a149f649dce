"""The validation set: images of varied content that are neither training nor test images.

Training choices (data, network, loss) are made on these images, never on the test images.
They come from sources the training and test splits never use (:data:`VALIDATION_SOURCES`):

* scikit-image's other shipped images -- camera (a photograph: smooth sky, fine grass), coins,
  moon (smooth, low contrast), page and text (printed text, small structures), cell, clock,
  horse (a binary silhouette, large structures), shepp_logan_phantom (flat regions), logo and
  colorwheel (graphics with saturated colour);
* matplotlib's other sample images -- Minduka_Present_Blue_Pack (a colour photograph) and
  logo2 (a graphic);
* procedural images with seeds no training run draws from -- a dead-leaves image
  (:func:`~edofproj.data.dead_leaves.dead_leaves_image`), a textured dead-leaves image and a smooth
  random field (:mod:`.procedural`).

Grey images are repeated to RGB, alpha is dropped. Each image is brought to the evaluation size by
the evaluation's scaling (:func:`~edofproj.data.test_images.fit_image`: by default the centre crop
at native resolution, small images scaled up to cover). ``edofproj evaluate RUN --validation``
scores a run on them.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import Callable

import numpy as np
import skimage.data
import torch
from matplotlib import cbook

from ..errors import EdofprojError
from ..imaging.image_io import read_image_array, to_unit_float
from .dead_leaves import dead_leaves_image, natural_color_palette
from .photos import as_rgb
from .procedural import smooth_field_image, textured_dead_leaves_image
from .test_images import fit_image

#: Seed of the procedural validation images (no training run is seeded with it by default).
VALIDATION_SEED = 20261123
#: Side (px) of the procedural validation images.
PROCEDURAL_SIZE = 384


def _skimage(name: str) -> np.ndarray:
    pixels = np.asarray(getattr(skimage.data, name)())
    if pixels.dtype == bool:
        return pixels.astype(np.uint8) * 255
    if pixels.dtype.kind == "f":
        return (np.clip(pixels, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    return pixels


def _matplotlib(filename: str) -> np.ndarray:
    return read_image_array(cbook.get_sample_data(filename, asfileobj=False))


def _procedural(kind: str) -> np.ndarray:
    generator = torch.Generator().manual_seed(VALIDATION_SEED + {"dead_leaves": 0, "textured": 1, "smooth": 2}[kind])
    palette = natural_color_palette(0.3)
    size = PROCEDURAL_SIZE
    if kind == "dead_leaves":
        image = dead_leaves_image(size, size, 1.0, 128.0, palette, generator)
    elif kind == "textured":
        image = textured_dead_leaves_image(size, size, 1.0, 128.0, palette, generator)
    else:
        image = smooth_field_image(size, size, palette, generator)
    return np.ascontiguousarray(image.permute(1, 2, 0).numpy())


VALIDATION_SOURCES: dict[str, Callable[[], np.ndarray]] = {
    **{
        f"skimage/{name}": partial(_skimage, name)
        for name in (
            "camera",
            "coins",
            "moon",
            "page",
            "text",
            "cell",
            "clock",
            "horse",
            "shepp_logan_phantom",
            "logo",
            "colorwheel",
        )
    },
    "matplotlib/Minduka_Present_Blue_Pack": partial(_matplotlib, "Minduka_Present_Blue_Pack.png"),
    "matplotlib/logo2": partial(_matplotlib, "logo2.png"),
    **{f"procedural/{kind}": partial(_procedural, kind) for kind in ("dead_leaves", "textured", "smooth")},
}
"""The validation images by name (module docstring)."""


def validation_images(
    size: tuple[int, int] | None, scaling: str = "crop", limit: int = 0
) -> list[tuple[str, torch.Tensor]]:
    """``[(name, (3, H, W) float32 in [0, 1])]`` of the validation set (sorted by name), each
    brought to ``size`` by ``scaling``; ``limit`` > 0 keeps the first ones. An image that cannot
    be loaded on this installation is skipped with a warning."""
    images: list[tuple[str, torch.Tensor]] = []
    for name in sorted(VALIDATION_SOURCES):
        if limit and len(images) >= limit:
            break
        try:
            pixels = as_rgb(np.asarray(VALIDATION_SOURCES[name]()))
        except (ImportError, OSError, ValueError, AttributeError, EdofprojError) as exc:
            warnings.warn(f"skipping validation image '{name}': {exc}")
            continue
        fitted = fit_image(pixels, size, scaling)
        array = fitted if fitted.dtype == np.float32 else to_unit_float(fitted)
        images.append((name, torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1)))))
    if not images:
        raise EdofprojError("no validation image can be loaded on this installation")
    return images
