"""Writing about the scores on textured surfaces (:mod:`edofproj.evaluation.surfaces`): the summary
tables (one per surface: mean SSIM, worst depth and mean PSNR over the score range), their Markdown,
and the figure (per surface, the reflectance, the goal and each method's projection, then SSIM over
depth)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..evaluation.results import format_span_mm
from ..evaluation.surfaces import (
    SURFACE_FIGURE_NAME,
    SURFACE_METRICS_NAME,
    SURFACE_SUMMARY_NAME,
    SurfaceEvaluation,
    surface_table,
)
from ..fileio import atomic_path, write_text_atomic
from ..methods.surface_variants import SURFACE_NET


class SummaryTable(NamedTuple):
    """A header and rows of text cells (printed by :func:`format_table`, written as Markdown)."""

    header: list[str]
    rows: list[list[str]]


def format_table(table: SummaryTable) -> str:
    """Plain-text columns, left-aligned, for the terminal."""
    widths = [max(len(str(row[i])) for row in [table.header, *table.rows]) for i in range(len(table.header))]
    lines = [
        "  ".join(str(cell).ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [table.header, *table.rows]
    ]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths), *lines[1:]])


def surface_summary_table(evaluation: SurfaceEvaluation, surface: str) -> SummaryTable:
    """Rows ``[method, mean SSIM, worst-depth SSIM (depth), mean PSNR]`` over the score range."""
    lo, hi = evaluation.range_mm
    sub = surface_table(evaluation, surface)
    rows = []
    for method in evaluation.methods:
        stats = sub.range_stats(method, "ssim", lo, hi)
        power = sub.range_stats(method, "psnr", lo, hi)
        rows.append(
            [method, f"{stats.mean:.4f}", f"{stats.worst:.4f} ({stats.worst_depth_mm:.0f} mm)", f"{power.mean:.2f}"]
        )
    return SummaryTable(
        [
            "method",
            f"SSIM mean {format_span_mm(lo, hi)} mm",
            "SSIM worst depth",
            f"PSNR mean (dB) {format_span_mm(lo, hi)} mm",
        ],
        rows,
    )


def surface_summary_markdown(evaluation: SurfaceEvaluation) -> str:
    """The section a report can include: one table per surface."""
    images = len({row["image"] for row in evaluation.table.rows})
    parts = [
        f"# Textured surfaces: {evaluation.run_dir}\n",
        f"Scores of the projection on each surface against the goal (the target scaled into the surface's range), "
        f"mean of {images} image(s); ambient illuminance {evaluation.ambient:g}. "
        f"`{SURFACE_METRICS_NAME}` has every score.\n",
    ]
    for surface in evaluation.surfaces:
        table = surface_summary_table(evaluation, surface)
        lines = ["| " + " | ".join(table.header) + " |", "|" + "---|" * len(table.header)]
        lines += ["| " + " | ".join(row) + " |" for row in table.rows]
        clipped = evaluation.clipped.get(surface, 0.0)
        parts.append(f"\n## {surface}\n\nGoal pixels out of the surface's range: at most {100 * clipped:.1f} %.\n")
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)


def plot_surface_figure(evaluation: SurfaceEvaluation, path: str | Path) -> None:
    """Per surface: the reflectance, the goal and each method's projection at the nearest scored depth
    (tiles wrapped as the other image grids, :func:`~.figures.grid_shape`, their text at the grids'
    size), then SSIM over depth across the figure's width, each method in its
    :func:`~.figures.method_colour`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .figures import GRID_DPI, GRID_TILE_IN, TILE_FONT_PT, grid_shape, method_colour

    lines, n_cols = grid_shape(2 + len(evaluation.methods))
    first = next((tile for tile in evaluation.examples.values() if tile is not None), None)
    aspect = first.shape[0] / first.shape[1] if first is not None else 1.0
    tile_h, plot_h = GRID_TILE_IN * aspect + 0.45, 2.8
    ratios = ([tile_h] * lines + [plot_h]) * len(evaluation.surfaces)
    fig = plt.figure(figsize=(GRID_TILE_IN * n_cols, sum(ratios) + 0.6))
    grid = fig.add_gridspec(len(ratios), n_cols, height_ratios=ratios)
    for r, surface in enumerate(evaluation.surfaces):
        top = r * (lines + 1)
        sub = surface_table(evaluation, surface)
        tiles: list[tuple[str, np.ndarray | None, float | None]] = [
            ("reflectance", evaluation.examples.get((surface, "reflectance")), None),
            ("goal", evaluation.examples.get((surface, "goal")), None),
        ]
        for method in evaluation.methods:
            mean = sub.mean("ssim", method=method, depth_mm=evaluation.example_depth_mm)
            tiles.append((method, evaluation.examples.get((surface, method)), mean))
        for index, (title, tile, value) in enumerate(tiles):
            ax = fig.add_subplot(grid[top + index // n_cols, index % n_cols])
            ax.set_xticks([])
            ax.set_yticks([])
            if tile is not None:
                ax.imshow(np.clip(tile, 0, 1))
            ax.set_title(title, fontsize=TILE_FONT_PT, fontweight="bold" if title == "doe+net" else "normal")
            if value is not None:
                ax.set_xlabel(f"SSIM {value:.3f}", fontsize=TILE_FONT_PT)
            if index % n_cols == 0:
                ax.set_ylabel(surface, fontsize=TILE_FONT_PT + 1)
        ax = fig.add_subplot(grid[top + lines, :])
        for method in evaluation.methods:
            means = sub.per_depth_means(method, "ssim")
            style = "-" if method == SURFACE_NET else ("--" if method.startswith("lens") else "-")
            width = 2.2 if method in ("doe+net", SURFACE_NET) else 1.3
            ax.plot(list(means), list(means.values()), style, marker=".", lw=width, label=method,
                    color=method_colour(method))  # fmt: skip
        ax.set_xlabel("screen depth (mm)", fontsize=TILE_FONT_PT)
        ax.set_ylabel("SSIM against the goal", fontsize=TILE_FONT_PT)
        ax.tick_params(labelsize=TILE_FONT_PT - 1)
        ax.grid(alpha=0.3)
        ax.set_title(f"{surface}: SSIM over depth", fontsize=TILE_FONT_PT)
        ax.legend(fontsize=TILE_FONT_PT - 2, ncol=2, loc="best")
    fig.suptitle(
        f"Projection on textured surfaces at {evaluation.example_depth_mm:.0f} mm (scored against the goal)",
        fontsize=TILE_FONT_PT + 1,
    )
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=GRID_DPI, format="png", bbox_inches="tight")
    plt.close(fig)


def write_surface_report(evaluation: SurfaceEvaluation) -> None:
    """The figure and ``surface_summary.md`` of a surface evaluation, beside its ``surface_metrics.csv``."""
    out = evaluation.out_dir
    figures = out / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    evaluation.files["figure"] = figures / SURFACE_FIGURE_NAME
    plot_surface_figure(evaluation, evaluation.files["figure"])
    evaluation.files["summary"] = out / SURFACE_SUMMARY_NAME
    write_text_atomic(evaluation.files["summary"], surface_summary_markdown(evaluation))
