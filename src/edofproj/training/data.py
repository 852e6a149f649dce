"""Training images and the held-out test images.

Three training sources (``data.source``), each with ``sample(batch_size, crop, generator)
-> (B, 3, crop, crop)`` float32 in ``[0, 1]`` that depends on nothing but the generator
(so a resumed or data-parallel run draws the same crops, :mod:`.sampling`):

* ``builtin`` -- photographs shipped inside installed packages (no download): scikit-image's
  ``skimage.data`` astronaut, coffee, chelsea, rocket, stereo_motorcycle (left view),
  hubble_deep_field, immunohistochemistry, retina, the grey textures brick, grass, gravel
  (repeated to RGB) and matplotlib's ``grace_hopper.jpg``. Random crops with random
  horizontal and vertical flips.
* ``folder`` -- every PNG/JPEG below ``data.folder`` (e.g. DIV2K), same crops and flips.
  Unreadable files and files smaller than the crop are skipped with one warning each.
* ``dead-leaves`` -- synthetic scale-invariant images (:func:`dead_leaves_labels`): opaque
  disks with radius density ``~ r^-3`` between ``data.dead_leaves_min_radius_px`` and
  ``data.dead_leaves_max_radius_px``, each of one colour drawn from pixels of the built-in
  training photographs (:func:`natural_color_palette`). About 20-40 ms per 128 x 128 image.

Held-out test images (:func:`build_test_images`): each image name (a file's path relative
to its folder) is ranked by its SHA-256 hash and the first ``round(test_fraction * n)`` of
the ranking (at least one, and at least one left for training) are held out. The split
depends on nothing but the names and the fraction. For the built-in set and the default
``test_fraction = 0.3`` the 4 test images are stereo_motorcycle, chelsea, gravel, coffee;
the 8 training images are hubble_deep_field, retina, grace_hopper, rocket, brick,
astronaut, immunohistochemistry, grass. ``dead-leaves`` is tested on the built-in test
photographs; ``folder`` on ``data.test_folder`` when given, else on its held-out share.
"""

from __future__ import annotations

import hashlib
import math
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import read_image_array, to_unit_float

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
FOLDER_CACHE_BYTES = 512 * 2**20  # decoded folder images kept in memory, at most this many bytes

# --------------------------------------------------------------------------- built-in photographs


def _skimage_photo(name: str) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        import skimage.data

        pixels = getattr(skimage.data, name)()
        return pixels[0] if isinstance(pixels, tuple) else pixels  # stereo_motorcycle: (left, right, disparity)

    return load


def _matplotlib_sample(filename: str) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        from matplotlib import cbook

        return read_image_array(cbook.get_sample_data(filename, asfileobj=False))

    return load


BUILTIN_PHOTOS: dict[str, Callable[[], np.ndarray]] = {
    **{name: _skimage_photo(name) for name in (
        "astronaut", "coffee", "chelsea", "rocket", "stereo_motorcycle", "hubble_deep_field",
        "immunohistochemistry", "retina", "brick", "grass", "gravel")},
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
    window = pixels[top: top + crop, left: left + crop]
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

    def sample(self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None) -> torch.Tensor:
        """``(batch_size, 3, crop, crop)``: each crop from a uniformly chosen image that is large enough."""
        crop = _check_crop(crop or self.crop)
        generator = generator or self.generator
        eligible = [i for i, p in enumerate(self.images) if min(p.shape[:2]) >= crop]
        if not eligible:
            largest = max(min(p.shape[:2]) for p in self.images)
            raise EdofprojError(f"crop {crop} px is larger than every training image (largest side allows {largest} px)")
        picks = torch.randint(0, len(eligible), (int(batch_size),), generator=generator).tolist()
        return torch.stack([random_crop(self.images[eligible[k]], crop, generator) for k in picks])


def builtin_photo_source(crop: int, test_fraction: float, seed: int = 0) -> PhotoSource:
    """The training share of the built-in photographs; those smaller than ``crop`` are skipped with a warning."""
    train, _ = builtin_split(test_fraction)
    images = []
    for name in train:
        pixels = load_builtin_photo(name)
        if min(pixels.shape[:2]) < crop:
            warnings.warn(f"built-in photograph '{name}' ({pixels.shape[1]}x{pixels.shape[0]}) is smaller than the "
                          f"crop {crop} px; skipped")
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
    """``(height, width)`` from the file header (Pillow, no decoding), or None if unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as picture:
            width, height = picture.size
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError):
        return None
    return height, width


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
                warnings.warn(f"skipping '{path}': {size[1]}x{size[0]} px is smaller than the crop {self.crop} px")
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

    def sample(self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None) -> torch.Tensor:
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


# --------------------------------------------------------------------------- dead leaves


def power_law_quantile(u: np.ndarray, exponent: int, min_radius: float, max_radius: float) -> np.ndarray:
    """Inverse CDF of the density ``~ r^-k`` on ``[r_min, r_max]`` at ``u in [0, 1)``.

    ``k = 1``: ``r = r_min (r_max / r_min)^u``; otherwise
    ``r = (r_min^(1-k) + u (r_max^(1-k) - r_min^(1-k)))^(1/(1-k))``.
    """
    if exponent == 1:
        return min_radius * (max_radius / min_radius) ** u
    e = 1.0 - exponent
    return (min_radius ** e + u * (max_radius ** e - min_radius ** e)) ** (1.0 / e)


def _power_integral(exponent: int, min_radius: float, max_radius: float) -> float:
    """``I_k = integral of r^-k over [r_min, r_max]``."""
    if exponent == 1:
        return math.log(max_radius / min_radius)
    e = 1.0 - exponent
    return (max_radius ** e - min_radius ** e) / e


def sample_dead_leaves_disks(count: int, height: int, width: int, min_radius: float, max_radius: float,
                             generator: torch.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` disks ``(radius, centre_x, centre_y)`` of a stationary Poisson process, front to back.

    The process has radius density ``p(r) ~ r^-3`` on ``[r_min, r_max]``. Pixel centres sit at
    integer coordinates ``0..W-1``, ``0..H-1``; a disk of radius ``r`` can cover one only if
    its centre lies in the box ``B(r) = [-r, W-1+r] x [-r, H-1+r]`` of area
    ``A(r) = (a + 2r)(b + 2r)``, ``a = W-1``, ``b = H-1``. Those disks have radius density
    ``q(r) ~ p(r) A(r) ~ ab r^-3 + 2(a+b) r^-2 + 4 r^-1`` -- a mixture of three truncated power
    laws, drawn exactly by :func:`power_law_quantile` -- and uniform centres in ``B(r)``.
    """
    count = int(count)
    a, b = width - 1.0, height - 1.0
    u = torch.rand((4, count), generator=generator, dtype=torch.float64).numpy()
    if max_radius == min_radius:
        radii = np.full(count, float(min_radius))
    else:
        exponents = (3, 2, 1)
        weights = np.array([a * b, 2 * (a + b), 4.0]) * [_power_integral(k, min_radius, max_radius) for k in exponents]
        component = np.searchsorted(np.cumsum(weights) / weights.sum(), u[0], side="right").clip(0, 2)
        radii = np.empty(count)
        for c, k in enumerate(exponents):
            chosen = component == c
            radii[chosen] = power_law_quantile(u[1, chosen], k, min_radius, max_radius)
    cx = -radii + u[2] * (a + 2 * radii)
    cy = -radii + u[3] * (b + 2 * radii)
    return radii, cx, cy


def disks_per_covering_layer(height: int, width: int, min_radius: float, max_radius: float) -> float:
    """How many disks of :func:`sample_dead_leaves_disks` cover each pixel once on average.

    With intensity ``lambda`` the coverage count is ``lambda pi E_p[r^2]`` and the number of disks
    that can touch the image ``lambda E_p[A(r)]``; so one layer is ``E_p[A(r)] / (pi E_p[r^2])``
    ``= (ab I_3 + 2(a+b) I_2 + 4 I_1) / (pi I_1)`` (``I_k`` the integrals of ``r^-k``).
    """
    a, b = width - 1.0, height - 1.0
    if max_radius == min_radius:
        return (a + 2 * min_radius) * (b + 2 * min_radius) / (math.pi * min_radius ** 2)
    i3, i2, i1 = (_power_integral(k, min_radius, max_radius) for k in (3, 2, 1))
    return (a * b * i3 + 2 * (a + b) * i2 + 4 * i1) / (math.pi * i1)


def paint_front_most(labels: np.ndarray, radii: np.ndarray, cx: np.ndarray, cy: np.ndarray, first_index: int) -> None:
    """``labels[y, x] = min(labels[y, x], k)`` for each disk ``k`` covering pixel centre ``(x, y)``.

    Disk ``j`` of the arrays has index ``first_index + j``; pixel centre ``(x, y)`` is covered
    when ``(x - cx)^2 + (y - cy)^2 <= r^2``. Disks are processed in groups of similar radius,
    each group vectorized over a square of candidate offsets.
    """
    height, width = labels.shape
    flat = labels.reshape(-1)
    index = first_index + np.arange(radii.size)
    group = np.ceil(np.log2(np.maximum(radii, 1.0))).astype(int)  # radius in (2^(g-1), 2^g]
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        reach = 2 ** int(g)
        offsets = np.arange(-reach, reach + 2)
        x = np.floor(cx[members]).astype(np.int64)[:, None] + offsets  # (n, m) candidate columns
        y = np.floor(cy[members]).astype(np.int64)[:, None] + offsets  # (n, m) candidate rows
        dx2 = np.where((x >= 0) & (x < width), (x - cx[members, None]) ** 2, np.inf)
        dy2 = np.where((y >= 0) & (y < height), (y - cy[members, None]) ** 2, np.inf)
        inside = dy2[:, :, None] + dx2[:, None, :] <= radii[members, None, None] ** 2
        k, i, j = np.nonzero(inside)
        np.minimum.at(flat, y[k, i] * width + x[k, j], index[members[k]])


def dead_leaves_labels(height: int, width: int, min_radius: float, max_radius: float,
                       generator: torch.Generator, max_disks: int = 2_000_000) -> np.ndarray:
    """A dead-leaves partition ``(H, W)`` (int64): at each pixel the index of the front-most disk.

    The scale-invariant dead-leaves model (Matheron; Lee, Mumford & Huang 2001): disks of
    radius density ``p(r) ~ r^-3`` on ``[min_radius, max_radius]`` fall at uniformly random
    places; each pixel shows the first disk that covers it. Disks are drawn front to back
    (:func:`sample_dead_leaves_disks`) until every pixel is covered, which gives an exact
    sample of the stationary model (not one that depends on a number of disks). Two pixels
    at distance ``d`` show the same disk with probability
    ``E|D ∩ (D + d)| / E|D ∪ (D + d)|`` (the expectation over the radius).
    """
    height, width = int(height), int(width)
    if height < 1 or width < 1:
        raise EdofprojError(f"dead-leaves image size {height}x{width} must be at least 1x1")
    if not (0 < min_radius <= max_radius and math.isfinite(max_radius)):
        raise EdofprojError(f"dead-leaves radii must satisfy 0 < min <= max, got {min_radius:g}, {max_radius:g}")
    unset = np.iinfo(np.int64).max
    labels = np.full((height, width), unset, dtype=np.int64)
    # The first batch aims at ln(H W) + 2 covering layers (usually enough for every pixel), later ones at 2 more.
    per_layer = disks_per_covering_layer(height, width, min_radius, max_radius)
    layers = math.log(height * width) + 2
    drawn = 0
    while drawn < max_disks:
        radii, cx, cy = sample_dead_leaves_disks(int(math.ceil(layers * per_layer)), height, width,
                                                 min_radius, max_radius, generator)
        paint_front_most(labels, radii, cx, cy, drawn)
        drawn += radii.size
        layers = 2.0
        if not np.any(labels == unset):
            return labels
    raise EdofprojError(f"{max_disks} dead-leaves disks did not cover the image; increase the minimum radius")


@lru_cache(maxsize=4)
def natural_color_palette(test_fraction: float = 0.3, count: int = 65536) -> np.ndarray:
    """``count`` RGB colours ``(count, 3)`` float32: pixels drawn uniformly from the built-in
    *training* photographs (each photograph contributes equally; fixed seed 0), so leaf colours
    follow the joint colour statistics of natural images and never come from a test image."""
    train, _ = builtin_split(test_fraction)
    rng = np.random.default_rng(0)
    per_photo = -(-count // len(train))
    colours = []
    for name in train:
        pixels = load_builtin_photo(name).reshape(-1, 3)
        colours.append(to_unit_float(pixels[rng.integers(0, len(pixels), per_photo)]))
    palette = np.concatenate(colours)[rng.permutation(per_photo * len(train))[:count]]
    palette.setflags(write=False)
    return palette


def dead_leaves_image(height: int, width: int, min_radius: float, max_radius: float, palette: np.ndarray,
                      generator: torch.Generator) -> torch.Tensor:
    """A dead-leaves image ``(3, H, W)`` float32: :func:`dead_leaves_labels` with one colour per disk,
    drawn uniformly from ``palette (n, 3)``."""
    labels = dead_leaves_labels(height, width, min_radius, max_radius, generator)
    used, inverse = np.unique(labels, return_inverse=True)
    picks = torch.randint(0, len(palette), (used.size,), generator=generator).numpy()
    image = np.asarray(palette, dtype=np.float32)[picks][inverse.reshape(height, width)]
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)))


class DeadLeavesSource:
    """Fresh dead-leaves images of natural colours (:func:`dead_leaves_image`) for every sample."""

    def __init__(self, crop: int, min_radius_px: float, max_radius_px: float, palette: np.ndarray, seed: int = 0):
        self.crop = _check_crop(crop)
        self.min_radius_px = float(min_radius_px)
        self.max_radius_px = float(max_radius_px)
        self.palette = palette
        self.generator = torch.Generator().manual_seed(int(seed))

    def sample(self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None) -> torch.Tensor:
        crop = _check_crop(crop or self.crop)
        generator = generator or self.generator
        return torch.stack([
            dead_leaves_image(crop, crop, self.min_radius_px, self.max_radius_px, self.palette, generator)
            for _ in range(int(batch_size))
        ])


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

    def sample(self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None) -> torch.Tensor:
        generator = generator or self.generator
        is_leaves = (torch.rand(int(batch_size), generator=generator) < self.dead_leaves_fraction).tolist()
        return torch.cat([
            (self.leaves if leaves else self.photos).sample(1, crop, generator) for leaves in is_leaves
        ])


# --------------------------------------------------------------------------- public API


def build_training_source(data_cfg, seed: int = 0):
    """The training source of a :class:`~edofproj.config.DataConfig`: an object with
    ``sample(batch_size, crop=None, generator=None) -> (B, 3, crop, crop)``. Without a
    generator, ``sample`` draws from the source's own generator seeded with ``seed``.
    ``data.dead_leaves_fraction > 0`` mixes dead leaves into a photo source (:class:`MixedSource`)."""
    if data_cfg.source == "dead-leaves" or data_cfg.dead_leaves_fraction > 0:
        leaves = DeadLeavesSource(data_cfg.crop, data_cfg.dead_leaves_min_radius_px, data_cfg.dead_leaves_max_radius_px,
                                  natural_color_palette(data_cfg.test_fraction), seed)
        if data_cfg.source == "dead-leaves":
            return leaves
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


def fit_to_size(pixels: np.ndarray, size: int | tuple[int, int]) -> np.ndarray:
    """Scale ``pixels (H, W, 3)`` to cover ``size`` (``n`` or ``(height, width)``), then crop the centre.

    Shrinking uses area averaging, enlarging bicubic interpolation (clipped to the dtype's range).
    """
    out_h, out_w = (int(size), int(size)) if np.isscalar(size) else (int(size[0]), int(size[1]))
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
    return pixels[top: top + out_h, left: left + out_w]


def _test_entries(data_cfg) -> list[tuple[str, Callable[[], np.ndarray]]]:
    if data_cfg.source in ("builtin", "dead-leaves"):
        _, test = builtin_split(data_cfg.test_fraction)
        return [(name, lambda name=name: load_builtin_photo(name)) for name in test]
    root = Path(data_cfg.test_folder or data_cfg.folder)
    files = find_image_files(root) if data_cfg.test_folder else folder_split(root, data_cfg.test_fraction)[1]
    if not files:
        raise EdofprojError(f"test folder '{root}' holds no PNG/JPEG files")
    return [(p.relative_to(root).as_posix(), lambda p=p: read_image_array(p)) for p in files]


def build_test_images(data_cfg, size: int | tuple[int, int] | None = None) -> list[tuple[str, torch.Tensor]]:
    """The held-out test images ``[(name, (3, H, W) float32 in [0, 1])]``, sorted by name.

    ``size``: None keeps each image's size; ``n`` or ``(height, width)`` scales each image to
    cover that size and crops the centre (:func:`fit_to_size`). ``data.max_test_images``
    (0: all) keeps the first ones. Unreadable files are skipped with a warning.
    """
    entries = _test_entries(data_cfg)
    limit = int(getattr(data_cfg, "max_test_images", 0) or 0)
    images = []
    for name, load in entries:
        if limit and len(images) >= limit:
            break
        try:
            pixels = as_rgb(load())
        except EdofprojError as exc:
            warnings.warn(f"skipping test image '{name}': {exc}")
            continue
        if size is not None:
            pixels = fit_to_size(pixels, size)
        images.append((name, torch.from_numpy(np.ascontiguousarray(to_unit_float(pixels).transpose(2, 0, 1)))))
    if not images:
        raise EdofprojError("no readable test image")
    return images
