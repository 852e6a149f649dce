"""Synthetic PSFs shared by the tests of the safe network and the display guard."""

from __future__ import annotations

import numpy as np
import torch


def gaussian_psfs(sigmas_px, window: int = 15, energy: float = 0.95) -> torch.Tensor:
    """Normalized Gaussian PSFs ``(N, 3, K, K)``, one per width in ``sigmas_px``, carrying ``energy``
    (the rest is haze)."""
    y, x = np.mgrid[-(window // 2) : window // 2 + 1, -(window // 2) : window // 2 + 1]
    stack = []
    for sigma in sigmas_px:
        g = np.exp(-(x**2 + y**2) / (2 * sigma**2))
        stack.append(np.repeat((energy * g / g.sum())[None], 3, axis=0))
    return torch.tensor(np.stack(stack), dtype=torch.float32)
