"""The images an evaluation is scored on: the run's held-out test images, or a folder.

By default the held-out split of the run's own data source
(:func:`edofproj.training.data.build_test_images`: for the built-in photographs, the 4 of 12
that training never sees). ``--images DIR`` scores every PNG/JPEG below ``DIR`` instead.
Each image is scaled to cover ``evaluation.image_size = [height, width]`` and centre-cropped
(``[]`` keeps native sizes); ``data.max_test_images`` (0: all) keeps the first ones by name.
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


def folder_images(folder: str | Path, size: tuple[int, int] | None, limit: int = 0) -> list[tuple[str, torch.Tensor]]:
    """``[(relative path, (3, H, W) float32)]`` of the images below ``folder``, sorted by name."""
    from ..imaging.image_io import read_image_array, to_unit_float
    from ..training.data import as_rgb, find_image_files, fit_to_size

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
        if size is not None:
            pixels = fit_to_size(pixels, size)
        array = np.ascontiguousarray(to_unit_float(pixels).transpose(2, 0, 1))
        images.append((path.relative_to(root).as_posix(), torch.from_numpy(array)))
    if not images:
        raise EdofprojError(f"--images '{folder}': no readable image")
    return images


def evaluation_images(cfg, images_dir: str | Path | None = None) -> list[tuple[str, torch.Tensor]]:
    """The images to score: ``images_dir`` when given, else the run's held-out test images."""
    size = evaluation_size(cfg)
    if images_dir is not None:
        return folder_images(images_dir, size, int(cfg.data.max_test_images or 0))
    from ..training.data import build_test_images

    return build_test_images(cfg.data, size)
