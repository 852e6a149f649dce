"""Held-out test images: the split's test share of the built-in photographs or of a folder.

For the built-in set and the default ``test_fraction = 0.3`` the 4 test images are
stereo_motorcycle, chelsea, gravel, coffee; the 8 training images are hubble_deep_field, retina,
grace_hopper, rocket, brick, astronaut, immunohistochemistry, grass. ``dead-leaves`` and ``procedural`` are tested on
the built-in test photographs; ``folder`` on ``data.test_folder`` when given, else on its
held-out share.

The images an evaluation is scored on (:func:`evaluation_images`) are the run's held-out test
images, or every image below ``--images DIR``. ``data.max_test_images`` (0: all) keeps the first
ones by name. Size (``evaluation.image_size = [height, width]``, ``[]``: native sizes) and scale
(``evaluation.image_scaling``):

* ``crop`` (default) -- the centre ``height x width`` of the image *at its native resolution*,
  the pixel scale of the training crops (random crops of the native images), so a network is
  scored on the kind of content it was trained on; an image smaller than the size is scaled up
  to cover it first;
* ``cover`` -- the whole image scaled to cover the size, then centre-cropped
  (:func:`fit_to_size`): large photographs are shrunk, which packs more detail into each pixel
  than the training crops have.

Images are never enlarged for scoring: an image smaller than the size on either side (a 60x60
image for 256x256) would be interpolated into a smooth picture that any method projects well,
raising the mean score. Such an image is skipped with a warning that says the rule, in both
scalings; when every image is smaller the evaluation stops with that message. Give larger images
or a smaller ``evaluation.image_size`` (``[]`` scores every image at its native size).
"""

from __future__ import annotations

import warnings
from functools import partial
from pathlib import Path
from typing import Callable, cast

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import read_image_array, to_unit_float
from .photos import as_rgb, builtin_split, find_image_files, folder_split, load_builtin_photo


def fit_to_size(pixels: np.ndarray, size: int | tuple[int, int]) -> np.ndarray:
    """Scale ``pixels (H, W, 3)`` to cover ``size`` (``n`` or ``(height, width)``), then crop the centre.

    Shrinking uses area averaging, enlarging bicubic interpolation (clipped to the dtype's range).
    """
    if np.isscalar(size):
        out_h = out_w = int(cast(int, size))
    else:
        height_width = cast("tuple[int, int]", size)
        out_h, out_w = int(height_width[0]), int(height_width[1])
    if out_h < 1 or out_w < 1:
        raise EdofprojError(f"test image size {size} must be positive")
    height, width = pixels.shape[:2]
    scale = max(out_h / height, out_w / width)
    if scale != 1.0:
        new_w, new_h = max(out_w, int(round(width * scale))), max(out_h, int(round(height * scale)))
        method = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
        pixels = cv2.resize(np.ascontiguousarray(pixels), (new_w, new_h), interpolation=method)
        height, width = pixels.shape[:2]
    top, left = (height - out_h) // 2, (width - out_w) // 2
    return pixels[top : top + out_h, left : left + out_w]


def _test_entries(data_cfg) -> list[tuple[str, Callable[[], np.ndarray]]]:
    if data_cfg.source in ("builtin", "dead-leaves", "procedural"):
        _, test = builtin_split(data_cfg.test_fraction)
        return [(name, partial(load_builtin_photo, name)) for name in test]
    root = Path(data_cfg.test_folder or data_cfg.folder)
    files = find_image_files(root) if data_cfg.test_folder else folder_split(root, data_cfg.test_fraction)[1]
    if not files:
        raise EdofprojError(f"test folder '{root}' holds no PNG/JPEG files")
    return [(p.relative_to(root).as_posix(), partial(read_image_array, p)) for p in files]


def build_test_images(
    data_cfg,
    size: int | tuple[int, int] | None = None,
    keep: Callable[[str, np.ndarray], bool] | None = None,
) -> list[tuple[str, torch.Tensor]]:
    """The held-out test images ``[(name, (3, H, W) float32 in [0, 1])]``, sorted by name.

    ``size``: None keeps each image's size; ``n`` or ``(height, width)`` scales each image to
    cover that size and crops the centre (:func:`fit_to_size`). ``data.max_test_images``
    (0: all) keeps the first ones. Unreadable files are skipped with a warning, and so are those
    for which ``keep(name, pixels (H, W, 3))`` (when given) is false.
    """
    entries = _test_entries(data_cfg)
    limit = int(getattr(data_cfg, "max_test_images", 0) or 0)
    images: list[tuple[str, torch.Tensor]] = []
    for name, load in entries:
        if limit and len(images) >= limit:
            break
        try:
            pixels = as_rgb(load())
        except EdofprojError as exc:
            warnings.warn(f"skipping test image '{name}': {exc}")
            continue
        if keep is not None and not keep(name, pixels):
            continue
        if size is not None:
            pixels = fit_to_size(pixels, size)
        images.append((name, torch.from_numpy(np.ascontiguousarray(to_unit_float(pixels).transpose(2, 0, 1)))))
    if not images:
        raise EdofprojError("no readable test image")
    return images


def evaluation_size(cfg) -> tuple[int, int] | None:
    size = cfg.evaluation.image_size
    return (int(size[0]), int(size[1])) if size else None


def fit_image(pixels: np.ndarray, size: tuple[int, int] | None, scaling: str) -> np.ndarray:
    """``pixels (H, W, 3)`` brought to ``size`` by ``scaling`` (module docstring)."""
    if size is None:
        return pixels
    height, width = pixels.shape[:2]
    if scaling == "crop" and height >= size[0] and width >= size[1]:
        top, left = (height - size[0]) // 2, (width - size[1]) // 2
        return pixels[top : top + size[0], left : left + size[1]]
    fitted = fit_to_size(pixels, size)
    return np.clip(fitted, 0.0, 1.0) if fitted.dtype.kind == "f" else fitted  # bicubic overshoot


def smaller_than_size(pixels: np.ndarray, size: tuple[int, int] | None) -> bool:
    """Whether ``pixels (H, W, 3)`` would have to be enlarged to reach ``size = (height, width)``."""
    return size is not None and (pixels.shape[0] < size[0] or pixels.shape[1] < size[1])


def _too_small_message(name: str, pixels: np.ndarray, size: tuple[int, int]) -> str:
    return (
        f"skipping '{name}': {pixels.shape[0]}x{pixels.shape[1]} px is smaller than the evaluation size "
        f"{size[0]}x{size[1]} (height x width; evaluation.image_size=[{size[0]},{size[1]}]): an enlarged image is "
        "smooth and scores too well; give a smaller --set evaluation.image_size=[H,W] to score it"
    )


def _none_large_enough(where: str, size: tuple[int, int]) -> EdofprojError:
    return EdofprojError(
        f"{where}: every image is smaller than the evaluation size {size[0]}x{size[1]} (height x width) and images "
        f"are not enlarged for scoring: give larger images or --set evaluation.image_size=[H,W] (or [] for native sizes)"
    )


def _as_tensor(pixels: np.ndarray) -> torch.Tensor:
    array = pixels if pixels.dtype == np.float32 else to_unit_float(pixels)
    return torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1)))


def folder_images(
    folder: str | Path, size: tuple[int, int] | None, scaling: str = "crop", limit: int = 0, enlarge: bool = False
) -> list[tuple[str, torch.Tensor]]:
    """``[(relative path, (3, H, W) float32)]`` of the images below ``folder``, sorted by name; those
    smaller than ``size`` are skipped with a warning unless ``enlarge`` (module docstring)."""
    root = Path(folder)
    files = find_image_files(root)
    if not files:
        raise EdofprojError(f"--images '{folder}' holds no PNG/JPEG files")
    images: list[tuple[str, torch.Tensor]] = []
    too_small = 0
    for path in files:
        if limit and len(images) >= limit:
            break
        try:
            pixels = as_rgb(read_image_array(path))
        except EdofprojError as exc:
            warnings.warn(f"skipping '{path}': {exc}")
            continue
        name = path.relative_to(root).as_posix()
        if size is not None and smaller_than_size(pixels, size) and not enlarge:
            warnings.warn(_too_small_message(name, pixels, size), stacklevel=2)
            too_small += 1
            continue
        images.append((name, _as_tensor(fit_image(pixels, size, scaling))))
    if not images:
        if too_small and size is not None:
            raise _none_large_enough(f"--images '{folder}'", size)
        raise EdofprojError(f"--images '{folder}': no readable image")
    return images


def evaluation_images(
    cfg, images_dir: str | Path | None = None, enlarge: bool = False
) -> list[tuple[str, torch.Tensor]]:
    """The images to score: ``images_dir`` when given, else the run's held-out test images.

    Images smaller than ``evaluation.image_size`` are skipped with a warning (module docstring);
    ``enlarge=True`` scales them up instead (a picture filling a projector frame, as the 3-D
    scene evaluation shows it)."""
    size = evaluation_size(cfg)
    scaling = cfg.evaluation.image_scaling
    if images_dir is not None:
        return folder_images(images_dir, size, scaling, int(cfg.data.max_test_images or 0), enlarge)
    too_small: list[str] = []

    def large_enough(name: str, pixels: np.ndarray) -> bool:
        if enlarge or not smaller_than_size(pixels, size):
            return True
        assert size is not None
        warnings.warn(_too_small_message(name, pixels, size), stacklevel=2)
        too_small.append(name)
        return False

    try:
        if scaling == "cover":
            return build_test_images(cfg.data, size, keep=large_enough)
        native = build_test_images(cfg.data, None, keep=large_enough)
    except EdofprojError:
        if too_small and size is not None:
            raise _none_large_enough("the run's test images", size) from None
        raise
    return [(name, _as_tensor(fit_image(image.permute(1, 2, 0).numpy(), size, scaling))) for name, image in native]
