"""Precomputed PSFs of a fixed DOE, interpolated per training sample.

A DOE that is not being optimized (the bare lens, a cubic plate, an axicon, a saved design,
or a learned one with ``train.train_doe = false``) has the same PSFs at every step, so they
are simulated once on a grid of depths and looked up instead of re-simulated each step
(for 2-D designs such as the cubic plate this turns a slow FFT per sample into a table
lookup).

The geometric blur diameter in projector pixels is linear in the inverse depth,

    b(z) = D T W |1/z - 1/v|,

so the grid is uniform in ``w = 1/z`` and a PSF at any depth in the range is the linear
interpolation between its two neighbours in ``w``:

    PSF(z) = (1 - t) PSF(w_i) + t PSF(w_{i+1}),   t = (1/z - w_i) / (w_{i+1} - w_i).

At the grid depths the lookup is exact. Between them the blur of neighbouring entries
differs by ``D T W (1/z_min - 1/z_max) / (n - 1)`` pixels (17.5 px / (n - 1) for the paper's
optics), which ``n`` (``train.psf_table_depths``) keeps a fraction of a pixel.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..errors import EdofprojError


class DepthPSFTable(nn.Module):
    """RGB PSFs ``(n, C, K, K)`` on a grid uniform in inverse depth; ``table(depths_m) -> (B, C, K, K)``."""

    psf: torch.Tensor  # buffer

    def __init__(self, psf: torch.Tensor, depths_m: np.ndarray) -> None:
        super().__init__()
        depths_m = np.asarray(depths_m, dtype=np.float64)
        if psf.dim() != 4 or psf.shape[0] != len(depths_m) or len(depths_m) < 2:
            raise EdofprojError(f"a PSF table needs >= 2 depths and PSFs (n, C, K, K), got {tuple(psf.shape)}")
        inverse = 1.0 / depths_m
        if not np.allclose(np.diff(inverse), inverse[1] - inverse[0], rtol=1e-6, atol=0):
            raise EdofprojError("the PSF table's depths must be uniformly spaced in 1/z")
        self.register_buffer("psf", psf.detach().clone())
        self.depths_m = depths_m
        self.inverse_start = float(inverse[0])
        self.inverse_step = float(inverse[1] - inverse[0])

    @classmethod
    def simulate(
        cls, simulator, doe, depth_min_m: float, depth_max_m: float, count: int, chunk: int = 16
    ) -> "DepthPSFTable":
        """Simulate ``count`` depths uniform in 1/z from ``depth_max_m`` to ``depth_min_m`` (no gradient)."""
        if count < 2:
            raise EdofprojError(f"train.psf_table_depths={count} must be >= 2")
        inverse = np.linspace(1.0 / depth_max_m, 1.0 / depth_min_m, count)
        depths = 1.0 / inverse
        with torch.no_grad():
            parts = [simulator(doe, depths[i : i + chunk]) for i in range(0, count, chunk)]
        return cls(torch.cat(parts).float(), depths)

    def forward(self, depths_m) -> torch.Tensor:
        """Interpolated PSFs ``(B, C, K, K)`` at ``depths_m`` (B,), which must lie inside the grid."""
        inverse = 1.0 / torch.as_tensor(np.asarray(depths_m, dtype=np.float64))
        position = (inverse - self.inverse_start) / self.inverse_step
        n = self.psf.shape[0]
        if torch.any(position < -1e-6) or torch.any(position > n - 1 + 1e-6):
            raise EdofprojError(
                f"depths {np.round(np.asarray(depths_m) * 1e3, 1).tolist()} mm are outside the PSF table's "
                f"{self.depths_m.min() * 1e3:.0f}-{self.depths_m.max() * 1e3:.0f} mm"
            )
        position = position.clamp(0, n - 1)
        lower = position.floor().long().clamp(max=n - 2)
        t = (position - lower).to(device=self.psf.device, dtype=self.psf.dtype)[:, None, None, None]
        lower = lower.to(self.psf.device)
        return (1 - t) * self.psf[lower] + t * self.psf[lower + 1]
