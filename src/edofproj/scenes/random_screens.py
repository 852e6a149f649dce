"""Random depth-varying screens for training: tilts, steps and smooth relief.

Each draw is a depth map ``(H, W)`` in metres inside ``[near_m, far_m]``, made in inverse depth
``w = 1/z`` (where the blur is linear, :mod:`edofproj.imaging.screens`) from depths drawn
uniformly in ``z``. With normalized pixel coordinates ``x, y`` in ``[-1, 1]``, one of four
kinds, equally likely:

* ``flat``:   ``w = 1/z_1``;
* ``tilt``:   ``w`` affine along a random direction ``phi``: ``w = 1/z_1 + (s + 1)/2 (1/z_2 - 1/z_1)``,
  ``s = (x cos phi + y sin phi) / (|cos phi| + |sin phi|)`` (a plane screen, any orientation);
* ``step``:   ``z_1`` on one side of a random straight edge ``x cos phi + y sin phi = c``
  (``|c| < 0.6``), ``z_2`` on the other (a depth edge);
* ``relief``: ``w = 1/z_1 + r (1/z_2 - 1/z_1)`` with ``r`` the sum of three random plane
  waves of at most two cycles across the image, scaled to ``[0, 1]`` (a smooth surface).

All draws come from the given generator (deterministic per training sample).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import EdofprojError

SCREEN_KINDS = ("flat", "tilt", "step", "relief")


def _uniform(generator: torch.Generator, count: int = 1) -> np.ndarray:
    return torch.rand(count, generator=generator, dtype=torch.float64).numpy()


def random_depth_map(
    generator: torch.Generator, height_px: int, width_px: int, near_m: float, far_m: float
) -> tuple[np.ndarray, str]:
    """A random screen ``(H, W)`` float64 in metres and its kind (module docstring)."""
    if not (0 < near_m < far_m):
        raise EdofprojError(f"random screens need 0 < near < far, got {near_m:g}-{far_m:g} m")
    u = _uniform(generator, 12)
    kind = SCREEN_KINDS[min(int(u[0] * len(SCREEN_KINDS)), len(SCREEN_KINDS) - 1)]
    z1, z2 = near_m + u[1:3] * (far_m - near_m)
    w1, w2 = 1.0 / z1, 1.0 / z2
    y, x = np.meshgrid(np.linspace(-1, 1, int(height_px)), np.linspace(-1, 1, int(width_px)), indexing="ij")
    phi = 2 * math.pi * u[3]
    along = x * math.cos(phi) + y * math.sin(phi)
    if kind == "flat":
        inverse = np.full(x.shape, w1)
    elif kind == "tilt":
        s = along / (abs(math.cos(phi)) + abs(math.sin(phi)))
        inverse = w1 + (s + 1) / 2 * (w2 - w1)
    elif kind == "step":
        inverse = np.where(along < 1.2 * (u[4] - 0.5), w1, w2)
    else:
        relief = np.zeros(x.shape)
        for k in range(3):
            angle = 2 * math.pi * u[5 + k]
            cycles = 0.25 + 1.75 * u[8 + k]
            relief += np.cos(math.pi * cycles * (x * math.cos(angle) + y * math.sin(angle)) + 2 * math.pi * u[11] * k)
        spread = relief.max() - relief.min()
        r = (relief - relief.min()) / spread if spread > 0 else np.zeros(x.shape)
        inverse = w1 + r * (w2 - w1)
    return 1.0 / inverse, kind
