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
    SURFACE_NET,
    SURFACE_SUMMARY_NAME,
    SurfaceEvaluation,
    surface_table,
)
from ..fileio import atomic_path, write_text_atomic


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
    """Per surface (rows): the reflectance, the goal and each method's projection at the nearest scored
    depth, then SSIM over depth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .figures import label_tile

    columns = 2 + len(evaluation.methods) + 1
    fig, axes = plt.subplots(
        len(evaluation.surfaces), columns, figsize=(1.9 * columns, 2.0 * len(evaluation.surfaces) + 0.6), squeeze=False
    )
    for r, surface in enumerate(evaluation.surfaces):
        sub = surface_table(evaluation, surface)
        tiles: list[tuple[str, np.ndarray | None, float | None]] = [
            ("reflectance", evaluation.examples.get((surface, "reflectance")), None)
        ]
        tiles.append(("goal", evaluation.examples.get((surface, "goal")), None))
        for method in evaluation.methods:
            mean = sub.mean("ssim", method=method, depth_mm=evaluation.example_depth_mm)
            tiles.append((method, evaluation.examples.get((surface, method)), mean))
        for c, (title, tile, value) in enumerate(tiles):
            ax = axes[r, c]
            if tile is not None:
                ax.imshow(np.clip(tile, 0, 1))
            if value is not None:
                ax.set_xlabel(f"SSIM {value:.3f}", fontsize=7)
            label_tile(ax, r, c, title, surface, title_size=7, row_label_size=8)
        ax = axes[r, -1]
        for index, method in enumerate(evaluation.methods):
            means = sub.per_depth_means(method, "ssim")
            style = "-" if method == SURFACE_NET else ("--" if method.startswith("lens") else ":")
            ax.plot(list(means), list(means.values()), style, marker=".", lw=1.2, label=method, color=f"C{index % 10}")
        ax.set_xlabel("depth (mm)", fontsize=7)
        ax.tick_params(labelsize=6)
        if r == 0:
            ax.set_title("SSIM over depth", fontsize=7)
            ax.legend(fontsize=5, loc="lower center")
    fig.suptitle(
        f"Projection on textured surfaces at {evaluation.example_depth_mm:.0f} mm (scored against the goal)",
        fontsize=9,
    )
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")
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
