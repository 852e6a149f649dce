"""The images an evaluation is scored on: the run's held-out test images, or a folder.

By default the held-out split of the run's own data source
(:func:`edofproj.training.data.build_test_images`: for the built-in photographs, the 4 of 12
that training never sees). ``--images DIR`` scores every PNG/JPEG below ``DIR`` instead.
``data.max_test_images`` (0: all) keeps the first ones by name.

Size (``evaluation.image_size = [height, width]``, ``[]``: native sizes) and scale
(``evaluation.image_scaling``):

* ``crop`` (default) -- the centre ``height x width`` of the image *at its native resolution*,
  the pixel scale of the training crops (random crops of the native images), so a network is
  scored on the kind of content it was trained on; an image smaller than the size is scaled up
  to cover it first;
* ``cover`` -- the whole image scaled to cover the size, then centre-cropped
  (:func:`edofproj.training.data.fit_to_size`): large photographs are shrunk, which packs more
  detail into each pixel than the training crops have.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError


def evaluation_size(cfg) -> tuple[int, int] | None:
    size = cfg.evaluation.image_size
    return (int(size[0]), int(size[1])) if size else None


def fit_image(pixels: np.ndarray, size: tuple[int, int] | None, scaling: str) -> np.ndarray:
    """``pixels (H, W, 3)`` brought to ``size`` by ``scaling`` (module docstring)."""
    from ..training.data import fit_to_size

    if size is None:
        return pixels
    height, width = pixels.shape[:2]
    if scaling == "crop" and height >= size[0] and width >= size[1]:
        top, left = (height - size[0]) // 2, (width - size[1]) // 2
        return pixels[top: top + size[0], left: left + size[1]]
    fitted = fit_to_size(pixels, size)
    return np.clip(fitted, 0.0, 1.0) if fitted.dtype.kind == "f" else fitted  # bicubic overshoot


def _as_tensor(pixels: np.ndarray) -> torch.Tensor:
    from ..imaging.image_io import to_unit_float

    array = pixels if pixels.dtype == np.float32 else to_unit_float(pixels)
    return torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1)))


def folder_images(folder: str | Path, size: tuple[int, int] | None, scaling: str = "crop",
                  limit: int = 0) -> list[tuple[str, torch.Tensor]]:
    """``[(relative path, (3, H, W) float32)]`` of the images below ``folder``, sorted by name."""
    from ..imaging.image_io import read_image_array
    from ..training.data import as_rgb, find_image_files

    root = Path(folder)
    files = find_image_files(root)
    if not files:
        raise EdofprojError(f"--images '{folder}' holds no PNG/JPEG files")
    images = []
    for path in files:
        if limit and len(images) >= limit:
            break
        try:
            pixels = as_rgb(read_image_array(path))
        except EdofprojError as exc:
            warnings.warn(f"skipping '{path}': {exc}")
            continue
        images.append((path.relative_to(root).as_posix(), _as_tensor(fit_image(pixels, size, scaling))))
    if not images:
        raise EdofprojError(f"--images '{folder}': no readable image")
    return images


def evaluation_images(cfg, images_dir: str | Path | None = None) -> list[tuple[str, torch.Tensor]]:
    """The images to score: ``images_dir`` when given, else the run's held-out test images."""
    size = evaluation_size(cfg)
    scaling = cfg.evaluation.image_scaling
    if images_dir is not None:
        return folder_images(images_dir, size, scaling, int(cfg.data.max_test_images or 0))
    from ..training.data import build_test_images

    if scaling == "cover":
        return build_test_images(cfg.data, size)
    native = build_test_images(cfg.data, None)
    return [(name, _as_tensor(fit_image(image.permute(1, 2, 0).numpy(), size, scaling))) for name, image in native]
