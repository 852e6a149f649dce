"""Figures written to ``<run>/figures/`` at the end of a training run (matplotlib, Agg backend).

* ``loss.png``: the training loss per step (and its MSE term) from ``train_log.csv``, with a
  moving average, on a log scale;
* ``doe_profile.png``: the fabricated (wrapped, quantized) height ``h(r)`` of a radial DOE, or
  the height map of a 2-D one;
* ``psf_depths.png``: the RGB PSFs across the training depth range (each panel scaled to its
  own maximum; the in-window energy fraction in the title).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from ..fileio import atomic_path  # noqa: E402


def _save(fig, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _moving_average(values: np.ndarray, width: int) -> np.ndarray:
    if len(values) < width or width < 2:
        return values
    kernel = np.ones(width) / width
    return np.convolve(values, kernel, mode="valid")


def plot_loss_curve(rows: list[dict[str, float]], path: str | Path) -> None:
    """Loss (and MSE) per step from the rows of :func:`edofproj.training.run_log.read_log`."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    if rows:
        steps = np.array([r["step"] for r in rows])
        for key, colour in (("loss", "C0"), ("mse", "C1")):
            values = np.array([r.get(key, math.nan) for r in rows], dtype=float)
            if np.all(np.isnan(values)):
                continue
            ax.plot(steps, values, color=colour, alpha=0.3, lw=0.8)
            width = max(1, len(values) // 20)
            smooth = _moving_average(values, width)
            ax.plot(steps[len(steps) - len(smooth) :], smooth, color=colour, lw=1.6, label=key)
        ax.set_yscale("log")
        ax.legend()
    ax.set_xlabel("step")
    ax.set_ylabel("training loss")
    ax.grid(alpha=0.3)
    _save(fig, Path(path))


def plot_doe_profile(doe, path: str | Path, samples: int = 1024) -> None:
    """The fabricated height profile (radial DOEs) or height map (2-D DOEs) in nm."""
    R = doe.aperture_radius_m
    with torch.no_grad():
        if doe.radially_symmetric:
            rings = max(samples // 2, 1)
            r = (torch.arange(rings, dtype=torch.float64, device=doe.device) + 0.5) * (R / rings)
            h = doe.height_m(r).double().cpu().numpy()
            fig, ax = plt.subplots(figsize=(7, 3.2))
            ax.step(r.cpu().numpy() * 1e3, h * 1e9, where="mid", lw=0.8)
            ax.set_xlabel("radius r (mm)")
            ax.set_ylabel("height h(r) (nm)")
            ax.set_xlim(0, R * 1e3)
            ax.set_ylim(0, doe.h2pi_m * 1e9 * 1.05)
            ax.axhline(doe.h2pi_m * 1e9, color="0.6", ls=":", lw=0.8, label="one wave (2 pi)")
            ax.grid(alpha=0.3)
        else:
            n = min(samples, 512)
            c = (torch.arange(n, dtype=torch.float64, device=doe.device) - n / 2 + 0.5) * (2 * R / n)
            y, x = torch.meshgrid(c, c, indexing="ij")
            h = doe.height_map_m(x, y).double().cpu().numpy()
            h[(x**2 + y**2).cpu().numpy() > R**2] = np.nan
            fig, ax = plt.subplots(figsize=(4.5, 4))
            image = ax.imshow(h * 1e9, extent=(-R * 1e3, R * 1e3, -R * 1e3, R * 1e3), cmap="viridis")
            fig.colorbar(image, ax=ax, label="height (nm)")
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
    ax.set_title(doe.describe(), fontsize=8)
    _save(fig, Path(path))


def plot_psfs_across_depth(psf: torch.Tensor, depths_m, path: str | Path) -> None:
    """One panel per depth: the RGB PSF ``(n, 3, K, K)`` normalized to its maximum."""
    psfs = psf.detach().float().cpu().numpy()
    n = psfs.shape[0]
    fig, axes = plt.subplots(1, n, figsize=(1.8 * n, 2.1), squeeze=False)
    for ax, p, z in zip(axes[0], psfs, np.asarray(depths_m)):
        rgb = np.moveaxis(p[:3] if p.shape[0] >= 3 else np.repeat(p[:1], 3, axis=0), 0, -1)
        ax.imshow(np.clip(rgb / max(rgb.max(), 1e-12), 0, 1), interpolation="nearest")
        ax.set_title(f"{z * 1e3:.0f} mm\nin window {p.sum(axis=(-1, -2)).mean():.2f}", fontsize=8)
        ax.axis("off")
    _save(fig, Path(path))
