"""The figure of ``edofproj scene render``: the image, the depth the projector sees, the
incidence angle and the simulated projection (matplotlib, Agg, PNG written atomically)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..fileio import atomic_path  # noqa: E402
from .raycast import SceneCast  # noqa: E402


def plot_scene_render(image: np.ndarray, cast: SceneCast, projection: np.ndarray, path: str | Path, title: str) -> None:
    """``image`` and ``projection`` ``(H, W, 3)`` in [0, 1]; depth in mm and incidence in degrees
    (grey where nothing is hit)."""
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.4))
    axes[0].imshow(np.clip(image, 0, 1))
    axes[0].set_title("projector image", fontsize=9)
    depth = axes[1].imshow(np.where(cast.hit, cast.depth_m * 1e3, np.nan), cmap="viridis")
    axes[1].set_title("axial depth (mm)", fontsize=9)
    fig.colorbar(depth, ax=axes[1], fraction=0.046)
    angle = axes[2].imshow(cast.incidence_deg, cmap="magma", vmin=0, vmax=90)
    axes[2].set_title("incidence angle (deg)", fontsize=9)
    fig.colorbar(angle, ax=axes[2], fraction=0.046)
    axes[3].imshow(np.clip(projection, 0, 1))
    axes[3].set_title("simulated projection", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_facecolor("0.5")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png", bbox_inches="tight")
    plt.close(fig)
