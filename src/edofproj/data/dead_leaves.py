"""Dead-leaves images: synthetic, scale-invariant training images.

Opaque disks with radius density ``~ r^-3`` between ``data.dead_leaves_min_radius_px`` and
``data.dead_leaves_max_radius_px`` (:func:`dead_leaves_labels`), each of one colour drawn from
pixels of the built-in training photographs (:func:`natural_color_palette`). About 20-40 ms per
128 x 128 image. A dead-leaves run is tested on the built-in test photographs.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from functools import lru_cache

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import to_unit_float
from .photos import _check_crop, builtin_split, load_builtin_photo

# --------------------------------------------------------------------------- dead leaves


def power_law_quantile(u: np.ndarray, exponent: int, min_radius: float, max_radius: float) -> np.ndarray:
    """Inverse CDF of the density ``~ r^-k`` on ``[r_min, r_max]`` at ``u in [0, 1)``.

    ``k = 1``: ``r = r_min (r_max / r_min)^u``; otherwise
    ``r = (r_min^(1-k) + u (r_max^(1-k) - r_min^(1-k)))^(1/(1-k))``.
    """
    if exponent == 1:
        return min_radius * (max_radius / min_radius) ** u
    e = 1.0 - exponent
    return (min_radius**e + u * (max_radius**e - min_radius**e)) ** (1.0 / e)


def _power_integral(exponent: int, min_radius: float, max_radius: float) -> float:
    """``I_k = integral of r^-k over [r_min, r_max]``."""
    if exponent == 1:
        return math.log(max_radius / min_radius)
    e = 1.0 - exponent
    return (max_radius**e - min_radius**e) / e


def sample_dead_leaves_disks(
    count: int, height: int, width: int, min_radius: float, max_radius: float, generator: torch.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        return (a + 2 * min_radius) * (b + 2 * min_radius) / (math.pi * min_radius**2)
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


def dead_leaves_labels(
    height: int,
    width: int,
    min_radius: float,
    max_radius: float,
    generator: torch.Generator,
    max_disks: int = 2_000_000,
) -> np.ndarray:
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
        radii, cx, cy = sample_dead_leaves_disks(
            int(math.ceil(layers * per_layer)), height, width, min_radius, max_radius, generator
        )
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


def dead_leaves_image(
    height: int, width: int, min_radius: float, max_radius: float, palette: np.ndarray, generator: torch.Generator
) -> torch.Tensor:
    """A dead-leaves image ``(3, H, W)`` float32: :func:`dead_leaves_labels` with one colour per disk,
    drawn uniformly from ``palette (n, 3)``."""
    labels = dead_leaves_labels(height, width, min_radius, max_radius, generator)
    used, inverse = np.unique(labels, return_inverse=True)
    picks = torch.randint(0, len(palette), (used.size,), generator=generator).numpy()
    image = np.asarray(palette, dtype=np.float32)[picks][inverse.reshape(height, width)]
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)))


class SyntheticImageSource(ABC):
    """A source of fresh synthetic images with disks of radii in ``[min_radius_px, max_radius_px]``
    and colours from ``palette``: each sample of a batch is one draw of :meth:`one` from the
    generator (the source's own, seeded by ``seed``, unless one is given)."""

    def __init__(self, crop: int, min_radius_px: float, max_radius_px: float, palette: np.ndarray, seed: int = 0):
        self.crop = _check_crop(crop)
        self.min_radius_px = float(min_radius_px)
        self.max_radius_px = float(max_radius_px)
        self.palette = palette
        self.generator = torch.Generator().manual_seed(int(seed))

    @abstractmethod
    def one(self, crop: int, generator: torch.Generator) -> torch.Tensor:
        """One ``(3, crop, crop)`` image."""

    def sample(
        self, batch_size: int, crop: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """``(batch_size, 3, crop, crop)`` images (``crop``: the source's by default)."""
        crop = _check_crop(crop or self.crop)
        generator = generator or self.generator
        return torch.stack([self.one(crop, generator) for _ in range(int(batch_size))])


class DeadLeavesSource(SyntheticImageSource):
    """Fresh dead-leaves images of natural colours (:func:`dead_leaves_image`) for every sample."""

    def one(self, crop: int, generator: torch.Generator) -> torch.Tensor:
        return dead_leaves_image(crop, crop, self.min_radius_px, self.max_radius_px, self.palette, generator)
