"""Figures of PSF banks: RGB PSFs across depth for designs side by side, radial profiles,
and the DOE height profiles."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from ..fileio import atomic_path  # noqa: E402


def psf_to_rgb(psf_chw: np.ndarray, gamma: float = 0.5) -> np.ndarray:
    """Display image of one RGB PSF: each tile scaled by its own peak, then a display gamma
    (0.5 shows the faint tails); a single-channel PSF is shown grey."""
    img = np.moveaxis(np.asarray(psf_chw, dtype=float), 0, -1)
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, axis=-1)
    peak = img.max()
    return np.clip(img / peak, 0, 1) ** gamma if peak > 0 else img


def plot_psf_comparison(panels, out_path, title: str | None = None) -> None:
    """``panels``: list of ``(label, doe, PSFBank)`` (same depths). Writes a PNG atomically.

    Rows 1..n: the PSF tiles of each design across depth (peak-normalized, gamma 0.5; the
    energy in the window under each tile). Last row: centre-row profiles (green channel,
    fraction of pupil energy per pixel, log scale) and the height profiles.
    """
    depths_mm = panels[0][2].depths_m * 1e3
    n_depths = len(depths_mm)
    n_designs = len(panels)
    fig = plt.figure(figsize=(max(8.0, 1.3 * n_depths), 1.6 * n_designs + 3.6), layout="constrained")
    subfigures = fig.subfigures(2, 1, squeeze=False, height_ratios=[1.6 * n_designs, 3.2])
    top, bottom = subfigures[0, 0], subfigures[1, 0]
    tiles = top.subplots(n_designs, n_depths, squeeze=False)
    for row, (label, _doe, bank) in enumerate(panels):
        psf = bank.psf.detach().cpu().numpy()
        energy = bank.energy_in_window.detach().cpu().numpy().mean(axis=1)
        for col in range(n_depths):
            ax = tiles[row, col]
            ax.imshow(psf_to_rgb(psf[col]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(f"{depths_mm[col]:.0f} mm", fontsize=9)
            ax.set_xlabel(f"E={energy[col]:.2f}", fontsize=7, labelpad=1)
            if col == 0:
                ax.set_ylabel(label, fontsize=10)
    ax_profile, ax_height = bottom.subplots(1, 2)
    styles = ["-", "--", ":", "-."]
    picks = sorted(set([0, n_depths // 2, n_depths - 1]))
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(picks)))
    for d, (label, doe, bank) in enumerate(panels):
        psf = bank.psf.detach().cpu().numpy()
        c = psf.shape[1] // 2  # green channel of RGB, or the single channel
        K = psf.shape[-1]
        offsets = np.arange(K) - K // 2
        for colour, i in zip(colours, picks):
            ax_profile.semilogy(
                offsets,
                np.maximum(psf[i, c, K // 2, :], 1e-7),
                styles[d % 4],
                color=colour,
                label=f"{label}, {depths_mm[i]:.0f} mm",
            )
        if ax_height is not None:
            R = doe.aperture_radius_m
            r = torch.linspace(0, R, 2000, dtype=torch.float64, device=doe.device)
            with torch.no_grad():
                if doe.radially_symmetric:
                    h = doe.height_m(r)
                else:
                    h = doe.height_map_m(r, torch.zeros_like(r))
            ax_height.plot(r.cpu().numpy() * 1e3, h.cpu().numpy() * 1e9, styles[d % 4], lw=0.8, label=label)
    ax_profile.set_xlabel("pixel offset (centre row)")
    ax_profile.set_ylabel("fraction of pupil energy")
    ax_profile.set_ylim(1e-6, 1.2)
    ax_profile.legend(fontsize=7, ncol=2)
    if ax_height is not None:
        ax_height.set_xlabel(
            "radius (mm)" + ("" if all(p[1].radially_symmetric for p in panels) else "; x for 2-D designs")
        )
        ax_height.set_ylabel("height (nm)")
        ax_height.legend(fontsize=8)
    fig.suptitle(
        title or "RGB PSFs across depth (each tile peak-normalized, gamma 0.5; E = energy in window)", fontsize=10
    )
    with atomic_path(out_path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
