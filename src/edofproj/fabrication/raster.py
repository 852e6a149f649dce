"""Raster images of a radial profile: the 16-bit height map and 8-bit mask previews (PNG).

Height map: a square of ``size`` pixels across the aperture diameter (pitch ``2R / size``,
pixel centres at ``(i - size/2 + 1/2) pitch``), one grey value per pixel

    grey = L * 65536 / N      (1 count = h_2pi / 65536;  height_nm = grey * h2pi_nm / 65536),

exact for every ``N = 2^k <= 65536``; the top level ``N - 1`` maps to ``65536 (N - 1) / N``.
Pixels outside the aperture are 0. Mask previews: 255 where the mask etches, 0 elsewhere,
96 outside the aperture. The GDSII file is the exact geometry; the rasters are previews
(the report says when the pitch does not resolve the narrowest zone).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from ..errors import EdofprojError
from .masks import MaskLayer
from .profile import RadialProfile

GREY_PER_WAVE = 65536
MAX_MAP_PX = 4096
MIN_MAP_PX = 512
PREVIEW_PX = 1024
OUTSIDE_PREVIEW = 96


def auto_map_size_px(profile: RadialProfile, px_per_zone: float = 2.0) -> int:
    """Even size giving ``px_per_zone`` pixels across the narrowest zone, clipped to 512-4096."""
    want = math.ceil(2 * profile.aperture_radius_m * px_per_zone / profile.narrowest_zone_m() - 1e-6)
    size = int(min(max(want, MIN_MAP_PX), MAX_MAP_PX))
    return size + size % 2


def pixel_radii_m(size: int, aperture_radius_m: float, rows: slice = slice(None)) -> np.ndarray:
    """Radius of each pixel centre (rows ``rows`` of a ``size`` x ``size`` grid across the aperture)."""
    pitch = 2 * aperture_radius_m / size
    c = (np.arange(size) - size / 2 + 0.5) * pitch
    return np.hypot(c[rows][:, None], c[None, :])


def height_map_grey(profile: RadialProfile, size: int, chunk_rows: int = 512) -> np.ndarray:
    """(size, size) uint16 grey values (see the module docstring)."""
    if size < 2:
        raise EdofprojError(f"height-map size {size} must be >= 2 pixels")
    grey = np.zeros((size, size), dtype=np.uint16)
    per_level = GREY_PER_WAVE // profile.levels
    R = profile.aperture_radius_m
    for start in range(0, size, chunk_rows):
        rows = slice(start, min(start + chunk_rows, size))
        r = pixel_radii_m(size, R, rows)
        values = (profile.level_at(r) * per_level).astype(np.uint16)
        values[r > R] = 0
        grey[rows] = values
    return grey


def mask_preview(mask: MaskLayer, aperture_radius_m: float, size: int = PREVIEW_PX) -> np.ndarray:
    """(size, size) uint8 preview of one mask."""
    r = pixel_radii_m(size, aperture_radius_m)
    image = np.where(mask.etched(r), 255, 0).astype(np.uint8)
    image[r > aperture_radius_m] = OUTSIDE_PREVIEW
    return image


def png_bytes(image: np.ndarray) -> bytes:
    """A uint8 or uint16 grey image encoded as PNG (OpenCV keeps 16 bits)."""
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise EdofprojError(f"cannot encode a {image.dtype} image of shape {image.shape} as PNG")
    return encoded.tobytes()


def read_grey_png(path: str | Path) -> np.ndarray:
    """Read a grey PNG unchanged (uint16 stays uint16)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise EdofprojError(f"cannot read PNG '{path}'")
    return image
