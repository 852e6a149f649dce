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
  random field (:mod:`.procedural`);
* colour classes (``colour/...``, :mod:`.colour`): the Minduka photograph with its blue primary at
  8 % of its level (a yellow-green scene, one primary nearly empty), dead leaves of saturated
  colours, the camera photograph darkened to a quarter, textured dead leaves in high key, a fine
  sinusoidal grating (periods of 3, 5 and 8 px, one per primary) and flat graphics (sharp-edged
  discs and bars in red, green, blue, yellow, cyan and magenta). :data:`COLOUR_CLASSES` are the ones training
  validates on (``train.validate_every``).

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
from .colour import dark, empty_primary, high_key, saturate
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


def _to_hwc(image: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(image.clamp(0, 1).permute(1, 2, 0).numpy().astype(np.float32))


def _chw(pixels: np.ndarray) -> torch.Tensor:
    array = np.asarray(as_rgb(pixels))
    array = array if array.dtype.kind == "f" else to_unit_float(array)
    return torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1))).float()


def _grating(size: int = PROCEDURAL_SIZE) -> np.ndarray:
    """Each primary a sinusoidal grating of its own period (3, 5, 8 px) and direction, in [0, 1]."""
    y, x = torch.meshgrid(
        torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij"
    )
    channels = []
    for period, angle in ((3.0, 0.0), (5.0, 1.0), (8.0, 2.2)):
        phase = (x * np.cos(angle) + y * np.sin(angle)) * (2 * np.pi / period)
        channels.append(0.5 + 0.45 * torch.sin(phase))
    return _to_hwc(torch.stack(channels))


def _flat_graphics(size: int = PROCEDURAL_SIZE) -> np.ndarray:
    """Sharp-edged discs and bars in red, green, blue, yellow, cyan and magenta; black left half, white right."""
    generator = torch.Generator().manual_seed(VALIDATION_SEED + 3)
    image = torch.zeros(3, size, size)
    image[:, :, size // 2 :] = 1.0
    colours = torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]], dtype=torch.float32)
    y, x = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    for index in range(24):
        colour = colours[index % len(colours)].view(3, 1, 1)
        cy, cx, r = (torch.rand(3, generator=generator) * torch.tensor([size, size, size / 8])).tolist()
        if index % 2:
            mask = (y - cy) ** 2 + (x - cx) ** 2 <= (r + 4) ** 2
        else:
            mask = ((y - cy).abs() <= r / 3 + 2) & ((x - cx).abs() <= 2 * r + 4)
        image = torch.where(mask, colour, image)
    return _to_hwc(image)


def _colour_class(kind: str) -> np.ndarray:
    if kind == "Minduka_near_empty_blue":
        return _to_hwc(empty_primary(_chw(_matplotlib("Minduka_Present_Blue_Pack.png")), 2, 0.08))
    if kind == "camera_dark":
        return _to_hwc(dark(_chw(_skimage("camera")), 0.25))
    if kind == "grating":
        return _grating()
    if kind == "flat_graphics":
        return _flat_graphics()
    generator = torch.Generator().manual_seed(VALIDATION_SEED + {"saturated_leaves": 4, "textured_high_key": 5}[kind])
    palette = natural_color_palette(0.3)
    size = PROCEDURAL_SIZE
    if kind == "saturated_leaves":
        return _to_hwc(saturate(dead_leaves_image(size, size, 1.0, 128.0, palette, generator), 2.5))
    return _to_hwc(high_key(textured_dead_leaves_image(size, size, 1.0, 128.0, palette, generator), 0.3))


#: The colour classes that training validates on (``train.validate_every``), in this order.
COLOUR_CLASSES = (
    "colour/Minduka_near_empty_blue",
    "colour/saturated_leaves",
    "colour/camera_dark",
    "colour/textured_high_key",
    "colour/grating",
    "colour/flat_graphics",
)

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
    **{name: partial(_colour_class, name.split("/", 1)[1]) for name in COLOUR_CLASSES},
}
"""The validation images by name (module docstring)."""


def validation_images(
    size: tuple[int, int] | None, scaling: str = "crop", limit: int = 0, names=None
) -> list[tuple[str, torch.Tensor]]:
    """``[(name, (3, H, W) float32 in [0, 1])]`` of the validation set (sorted by name, or the
    ``names`` given, in their order), each brought to ``size`` by ``scaling``; ``limit`` > 0 keeps
    the first ones. An image that cannot be loaded on this installation is skipped with a warning."""
    images: list[tuple[str, torch.Tensor]] = []
    for name in sorted(VALIDATION_SOURCES) if names is None else names:
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
