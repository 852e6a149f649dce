"""Photographs: the built-in set, image folders, their deterministic train/test split, random crops.

* ``builtin`` -- photographs shipped inside installed packages (no download): scikit-image's
  ``skimage.data`` astronaut, coffee, chelsea, rocket, stereo_motorcycle (left view),
  hubble_deep_field, immunohistochemistry, retina, the grey textures brick, grass, gravel
  (repeated to RGB) and matplotlib's ``grace_hopper.jpg``. Random crops with random
  horizontal and vertical flips.
* ``folder`` -- every image file below ``data.folder`` (e.g. DIV2K) whose extension is in
  :data:`edofproj.imaging.image_io.IMAGE_EXTENSIONS`, same crops and flips. Unreadable files
  and files smaller than the crop are skipped with one warning each.

The split (:func:`split_names`): each image name (a file's path relative to its folder) is
ranked by its SHA-256 hash and the first ``round(test_fraction * n)`` of the ranking (at least
one, and at least one left for training) are held out. It depends on nothing but the names
and the fraction.
"""

from __future__ import annotations

import hashlib
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import skimage.data
import torch

from ..errors import EdofprojError
from ..imaging.image_io import IMAGE_EXTENSIONS, image_file_size, read_image_array, to_unit_float

FOLDER_CACHE_BYTES = 512 * 2**20  # decoded folder images kept in memory, at most this many bytes

# --------------------------------------------------------------------------- built-in photographs


def _skimage_photo(name: str) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        pixels = getattr(skimage.data, name)()
        return pixels[0] if isinstance(pixels, tuple) else pixels  # stereo_motorcycle: (left, right, disparity)

    return load


def _matplotlib_sample(filename: str) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        from matplotlib import cbook  # here, not at import: matplotlib takes a sixth of a second to import

        return read_image_array(cbook.get_sample_data(filename, asfileobj=False))

    return load


BUILTIN_PHOTOS: dict[str, Callable[[], np.ndarray]] = {
    **{
        name: _skimage_photo(name)
        for name in (
            "astronaut",
            "coffee",
            "chelsea",
            "rocket",
            "stereo_motorcycle",
            "hubble_deep_field",
            "immunohistochemistry",
            "retina",
            "brick",
            "grass",
            "gravel",
        )
    },
    "grace_hopper": _matplotlib_sample("grace_hopper.jpg"),
}
"""Photographs that ship inside scikit-image and matplotlib (checked to load without network)."""


def as_rgb(pixels: np.ndarray) -> np.ndarray:
    """An ``(H, W)``, ``(H, W, 1)``, ``(H, W, 3)`` or ``(H, W, 4)`` array as RGB ``(H, W, 3)`` (alpha dropped)."""
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3 or pixels.shape[-1] not in (1, 3, 4):
        raise EdofprojError(f"an image must be (H, W) or (H, W, 1|3|4), got shape {pixels.shape}")
    if pixels.shape[-1] == 1:
        return np.repeat(pixels, 3, axis=-1)
    return np.ascontiguousarray(pixels[..., :3])


@lru_cache(maxsize=None)
def load_builtin_photo(name: str) -> np.ndarray:
    """Built-in photograph ``name`` as RGB ``uint8`` ``(H, W, 3)`` (read-only, cached)."""
    if name not in BUILTIN_PHOTOS:
        raise EdofprojError(f"unknown built-in photograph '{name}' (known: {', '.join(BUILTIN_PHOTOS)})")
    try:
        pixels = as_rgb(np.asarray(BUILTIN_PHOTOS[name]()))
    except (ImportError, OSError, ValueError) as exc:  # a trimmed installation without the data file
        raise EdofprojError(f"built-in photograph '{name}' cannot be loaded here: {exc}") from None
    pixels.setflags(write=False)
    return pixels


# --------------------------------------------------------------------------- deterministic split


def split_names(names: Sequence[str], test_fraction: float) -> tuple[list[str], list[str]]:
    """``(train, test)``: the ``round(test_fraction * n)`` names first in SHA-256 order are held out.

    At least one name goes to each side; both lists come back sorted. Needs two or more names.
    """
    names = sorted(set(names))
    if len(names) < 2:
        raise EdofprojError(f"a train/test split needs at least 2 images, got {len(names)}")
    if not 0.0 < test_fraction < 1.0:
        raise EdofprojError(f"test_fraction={test_fraction} must be in (0, 1)")
    n_test = min(max(int(round(test_fraction * len(names))), 1), len(names) - 1)
    ranked = sorted(names, key=lambda name: hashlib.sha256(name.encode("utf-8")).hexdigest())
    test = set(ranked[:n_test])
    return [n for n in names if n not in test], [n for n in names if n in test]


def builtin_split(test_fraction: float) -> tuple[list[str], list[str]]:
    """``(train, test)`` names of the built-in photographs."""
    return split_names(list(BUILTIN_PHOTOS), test_fraction)


# --------------------------------------------------------------------------- crops


def random_crop(pixels: np.ndarray, crop: int, generator: torch.Generator) -> torch.Tensor:
    """A random ``crop x crop`` window of ``pixels (H, W, 3)``, flipped left-right and up-down with
    probability 1/2 each; float32 ``(3, crop, crop)`` in ``[0, 1]``."""
    height, width = pixels.shape[:2]
    top = int(torch.randint(0, height - crop + 1, (), generator=generator))
    left = int(torch.randint(0, width - crop + 1, (), generator=generator))
    flip_lr, flip_ud = (torch.rand(2, generator=generator) < 0.5).tolist()
    window = pixels[top : top + crop, left : left + crop]
    if flip_lr:
        window = window[:, ::-1]
    if flip_ud:
        window = window[::-1]
    return torch.from_numpy(np.ascontiguousarray(to_unit_float(np.ascontiguousarray(window)).transpose(2, 0, 1)))


def _check_crop(crop: int) -> int:
    if int(crop) < 1:
        raise EdofprojError(f"crop size {crop} must be >= 1")
    return int(crop)


class PhotoSource:
    """Random crops and flips from images held in memory: ``[(name, (H, W, 3) uint8/uint16)]``."""

    def __init__(self, images: Sequence[tuple[str, np.ndarray]], crop: int, seed: int = 0):
        if not images:
            raise EdofprojError("a photo source needs at least one image")
        self.names = [name for name, _ in images]
        self.images = [pixels for _, pixels in images]
        self.crop = _check_crop(crop)
        self.generator = torch.Generator().manual_seed(int(seed))

    def __len__(self) -> int:
        return len(self.images)

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """``(batch_size, 3, crop, crop)``: each crop from a uniformly chosen image that is large enough."""
        crop = _check_crop(crop or self.crop)
        generator = generator or self.generator
        eligible = [i for i, p in enumerate(self.images) if min(p.shape[:2]) >= crop]
        if not eligible:
            largest = max(min(p.shape[:2]) for p in self.images)
            raise EdofprojError(
                f"crop {crop} px is larger than every training image (largest side allows {largest} px)"
            )
        picks = torch.randint(0, len(eligible), (int(batch_size),), generator=generator).tolist()
        return torch.stack([random_crop(self.images[eligible[k]], crop, generator) for k in picks])


def builtin_photo_source(crop: int, test_fraction: float, seed: int = 0) -> PhotoSource:
    """The training share of the built-in photographs; those smaller than ``crop`` are skipped with a warning."""
    train, _ = builtin_split(test_fraction)
    images = []
    for name in train:
        pixels = load_builtin_photo(name)
        if min(pixels.shape[:2]) < crop:
            warnings.warn(
                f"built-in photograph '{name}' ({pixels.shape[0]}x{pixels.shape[1]}, height x width) is smaller than the "
                f"crop {crop} px; skipped"
            )
            continue
        images.append((name, pixels))
    if not images:
        raise EdofprojError(f"no built-in training photograph is at least {crop}x{crop} px; use a smaller data.crop")
    return PhotoSource(images, crop, seed)


# --------------------------------------------------------------------------- image folders


def find_image_files(folder: str | Path) -> list[Path]:
    """PNG/JPEG files below ``folder`` (recursive, case-insensitive extensions), sorted."""
    root = Path(folder)
    if not root.is_dir():
        raise EdofprojError(f"image folder '{folder}' does not exist or is not a directory")
    return sorted(p for p in root.rglob("*") if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())


def probe_image_size(path: Path) -> tuple[int, int] | None:
    """``(height, width)`` from the file header (no decoding; any size, a huge one included), or None
    if unreadable: :func:`edofproj.imaging.image_io.image_file_size`."""
    return image_file_size(path)


class FolderSource:
    """Random crops and flips from image files, decoded on demand (kept in memory up to a budget).

    Files whose header cannot be read or that are smaller than ``crop`` are skipped when the
    source is built; a file that fails to decode later is skipped at that point (the draw
    moves on to the next usable file in order, so samples still depend only on the generator).
    One warning per skipped file.
    """

    def __init__(self, paths: Sequence[Path], crop: int, seed: int = 0, root: Path | None = None):
        self.crop = _check_crop(crop)
        self.root = root
        self.paths: list[Path] = []
        self.sizes: list[tuple[int, int]] = []
        for path in paths:
            size = probe_image_size(path)
            if size is None:
                warnings.warn(f"skipping unreadable image '{path}'")
            elif min(size) < self.crop:
                warnings.warn(
                    f"skipping '{path}': {size[0]}x{size[1]} px (height x width) is smaller than the crop {self.crop} px"
                )
            else:
                self.paths.append(path)
                self.sizes.append(size)
        if not self.paths:
            where = f" in '{root}'" if root is not None else ""
            raise EdofprojError(f"no readable PNG/JPEG image of at least {self.crop}x{self.crop} px{where}")
        self.generator = torch.Generator().manual_seed(int(seed))
        self._cache: dict[int, np.ndarray] = {}
        self._cached_bytes = 0
        self._broken: set[int] = set()

    def __len__(self) -> int:
        return len(self.paths)

    def _pixels(self, index: int) -> np.ndarray | None:
        if index in self._cache:
            return self._cache[index]
        if index in self._broken:
            return None
        try:
            pixels = read_image_array(self.paths[index])
        except EdofprojError:
            warnings.warn(f"skipping unreadable image '{self.paths[index]}'")
            self._broken.add(index)
            return None
        if self._cached_bytes + pixels.nbytes <= FOLDER_CACHE_BYTES:
            self._cache[index] = pixels
            self._cached_bytes += pixels.nbytes
        return pixels

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """``(batch_size, 3, crop, crop)`` from uniformly chosen files at least ``crop`` px on each side."""
        crop = _check_crop(crop or self.crop)
        generator = generator or self.generator
        eligible = [i for i, size in enumerate(self.sizes) if min(size) >= crop]
        if not eligible:
            raise EdofprojError(f"crop {crop} px is larger than every image of the folder")
        crops = []
        for pick in torch.randint(0, len(eligible), (int(batch_size),), generator=generator).tolist():
            for step in range(len(eligible)):
                pixels = self._pixels(eligible[(pick + step) % len(eligible)])
                if pixels is not None:
                    break
            else:
                raise EdofprojError("none of the folder's images can be decoded")
            crops.append(random_crop(pixels, crop, generator))
        return torch.stack(crops)


def folder_split(folder: str | Path, test_fraction: float) -> tuple[list[Path], list[Path]]:
    """``(train, test)`` files of a folder, split by :func:`split_names` on their relative paths."""
    root = Path(folder)
    files = find_image_files(root)
    if not files:
        raise EdofprojError(f"image folder '{folder}' holds no PNG/JPEG files")
    by_name = {p.relative_to(root).as_posix(): p for p in files}
    train, test = split_names(list(by_name), test_fraction)
    return [by_name[n] for n in train], [by_name[n] for n in test]
