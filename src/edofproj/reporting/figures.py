"""Figures of an evaluation (matplotlib, Agg backend, PNG written atomically).

* :func:`plot_metric_vs_depth` -- a metric against the screen depth, one line per method,
  the scored depth range shaded;
* :func:`plot_designs_vs_depth` -- the same for every optical design with its best blind (solid) and
  non-blind (dashed) compensation (:mod:`.designs`), one colour per design;
* :func:`plot_comparison` -- the side-by-side grid of the paper's Fig. 6: rows = depths,
  columns = the target and each method, PSNR / SSIM (and LPIPS when available) on each tile,
  the best value of each row in bold red;
* :func:`plot_tilted` -- the same for the tilted screen (one row);
* :func:`plot_captured_comparison` -- the same for real captures (rows = images);
* :func:`plot_training_curves` -- the training loss of every run, one panel each (the others in grey).

The PSF figure is :func:`edofproj.reporting.psf_plots.plot_psf_comparison` and the DOE profile
:func:`edofproj.runs.figures.plot_doe_profile`.

Every plot that draws methods as lines takes their colours from :func:`method_colour` (one colour
per method, the same in every figure, no two methods alike) and PSNR axes stop at
:data:`PSNR_AXIS_MAX_DB` (:func:`clip_psnr_axis`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..evaluation.results import METRIC_LABELS, MetricsTable, better  # noqa: E402
from ..fileio import atomic_path  # noqa: E402
from ..methods.catalogue import CLASSIC_ELEMENTS, METHOD_NAMES, METHODS, OURS  # noqa: E402
from .designs import DESIGN_LABELS, DesignBest  # noqa: E402

#: Metrics written on the tiles of the comparison figures, with their short labels (paper Fig. 6).
TILE_METRICS = (("psnr", "P", "{:.2f}"), ("ssim", "S", "{:.3f}"), ("lpips", "L", "{:.3f}"))

#: Image grids: at most this many tiles side by side (a row of more wraps onto the next lines), each
#: ``GRID_TILE_IN`` inches wide at ``GRID_DPI``, with the scores in ``TILE_FONT_PT`` points. At the
#: width of a report page (about 800 px) a label is then about 12 px high, whatever the number of methods.
GRID_MAX_COLUMNS = 4
GRID_TILE_IN = 2.4
GRID_DPI = 120
TILE_FONT_PT = 10


def _save(fig, path: str | Path, dpi: int = 110) -> None:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    plt.close(fig)


def label_tile(
    ax, row: int, column: int, title: str, row_label: str, title_size: float = 9, row_label_size: float = 9
) -> None:
    """A tile of a grid of pictures: its column's title above the first row, its row's label left of
    the first column, no ticks."""
    if row == 0:
        ax.set_title(title, fontsize=title_size)
    if column == 0:
        ax.set_ylabel(row_label, fontsize=row_label_size)
    ax.set_xticks([])
    ax.set_yticks([])


#: Variants of a method drawn in its lighter shade (:func:`method_colour`).
VARIANT_SUFFIXES = ("+photometric",)


def method_colour(name: str) -> tuple | str:
    """The colour of method ``name`` in every figure: ours (``doe+net``) black; each other method of
    :data:`~edofproj.methods.catalogue.METHOD_NAMES` but the classic elements' linear baselines the dark
    shade of its own pair of matplotlib's ``tab20`` map, in their order (10 methods, 10 pairs: no two
    alike); the classic elements' linear baselines (``X``, ``X+wiener``, ``X+ensemble``) and the methods
    past those ten (``multifocal+net``, ``doe+cls``) each their own colour of ``tab20b``, in their order; a variant (``NAME+photometric``) the light shade of its method's pair
    (ours' variant grey); any other name a colour of ``tab20b`` fixed by its letters."""
    for suffix in VARIANT_SUFFIXES:
        if name.endswith(suffix):
            base = name[: -len(suffix)]
            if base == OURS:
                return "0.55"
            if base in _PAIRED:
                return plt.cm.tab20(2 * _PAIRED.index(base) + 1)
    if name == OURS:
        return "black"
    if name in _PAIRED:
        return plt.cm.tab20(2 * _PAIRED.index(name))
    if name in _SINGLE_SHADE:
        return plt.cm.tab20b(_SINGLE_SHADE.index(name) % 20)
    return plt.cm.tab20b(sum(name.encode()) % 20)


#: The classic elements' linear baselines (a ``tab20b`` colour each), and the other methods but ours (a
#: ``tab20`` pair each).
_OTHERS = [m.name for m in METHODS if m.name != OURS and m.optics not in CLASSIC_ELEMENTS]
#: (``tab20`` has 10 pairs: methods past the tenth, ``multifocal+net`` and ``doe+cls``, take a ``tab20b`` colour.)
_PAIRED = _OTHERS[:10]
_SINGLE_SHADE = [m.name for m in METHODS if m.optics in CLASSIC_ELEMENTS] + _OTHERS[10:]
assert len(set(_SINGLE_SHADE)) <= 20 and set(_PAIRED) | set(_SINGLE_SHADE) | {OURS} == set(METHOD_NAMES)


def _method_style(index: int, name: str) -> dict:
    """Ours thick and black, the rest in their :func:`method_colour`; lens-based dashed, DOE-based solid."""
    if name == OURS:
        return dict(color="black", lw=2.4, ls="-", marker="o", ms=4, zorder=5)
    return dict(color=method_colour(name), lw=1.3, ls="--" if name.startswith("lens") else "-", marker=".", ms=5)


#: The top of a PSNR axis: higher values (a method at the one depth where it is exact, e.g. CLS at the
#: focus) are drawn on the top edge, marked, so that they do not flatten every other curve.
PSNR_AXIS_MAX_DB = 50.0


def clip_psnr_axis(ax, values: Sequence[float]) -> bool:
    """Stop the y-axis at :data:`PSNR_AXIS_MAX_DB` when a value is above it; True when it did."""
    finite = [v for v in values if np.isfinite(v)]
    if not finite or max(finite) <= PSNR_AXIS_MAX_DB:
        return False
    low = min(finite)
    ax.set_ylim(max(0.0, low - 0.05 * (PSNR_AXIS_MAX_DB - low)), PSNR_AXIS_MAX_DB)
    return True


def plot_metric_vs_depth(
    table: MetricsTable,
    metric: str,
    path: str | Path,
    scored_range_mm: tuple[float, float] | None = None,
    title: str | None = None,
) -> None:
    """Mean ``metric`` over the images against depth, one line per method; the depth range the
    summaries score (``evaluation.score_range_mm``) shaded."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    if scored_range_mm is not None:
        ax.axvspan(*scored_range_mm, color="0.92", zorder=0, label="scored range")
    values = []
    for index, method in enumerate(table.methods()):
        means = table.per_depth_means(method, metric)
        depths = sorted(means)
        ax.plot(depths, [means[z] for z in depths], label=method, **_method_style(index, method))
        values += [means[z] for z in depths]
    default_title = f"{METRIC_LABELS.get(metric, metric)} vs depth (mean over the test images)"
    if metric == "psnr" and clip_psnr_axis(ax, values):
        above = [
            (z, v, m)
            for m in table.methods()
            for z, v in table.per_depth_means(m, metric).items()
            if v > PSNR_AXIS_MAX_DB
        ]
        for z, v, m in above:
            ax.plot([z], [PSNR_AXIS_MAX_DB], marker="^", ms=8, color=method_colour(m), clip_on=False, zorder=6)
            ax.annotate(f"{v:.0f}", (z, PSNR_AXIS_MAX_DB), xytext=(0, -14), textcoords="offset points",
                        ha="center", fontsize=7, color=method_colour(m))  # fmt: skip
        default_title += f"; axis clipped at {PSNR_AXIS_MAX_DB:.0f} dB (▲: higher, value written)"
    ax.set_xlabel("screen depth z (mm)")
    ax.set_ylabel(
        METRIC_LABELS.get(metric, metric) + ("" if metric not in ("lpips", "dists") else " (lower is better)")
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="best")
    ax.set_title(title or default_title, fontsize=10)
    _save(fig, path)


#: The colour of each optical design in :func:`plot_designs_vs_depth` (the learned DOE black, as ours).
DESIGN_COLOURS = {
    "lens": "tab:blue",
    "doe": "black",
    "cubic": "tab:orange",
    "axicon": "tab:green",
    "multifocal": "tab:purple",
}


def plot_designs_vs_depth(
    table: MetricsTable,
    best: Sequence[DesignBest],
    path: str | Path,
    scored_range_mm: tuple[float, float] | None = None,
    metric: str = "ssim",
) -> None:
    """Mean ``metric`` over the images against depth of each method of ``best``
    (:func:`~edofproj.reporting.designs.best_compensations`): the colour of its design
    (:data:`DESIGN_COLOURS`), solid when blind, dashed when non-blind; the scored range shaded."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    if scored_range_mm is not None:
        ax.axvspan(*scored_range_mm, color="0.92", zorder=0, label="scored range")
    for choice in best:
        means = table.per_depth_means(choice.method, metric)
        depths = sorted(means)
        blind = choice.kind == "blind"
        ax.plot(
            depths,
            [means[z] for z in depths],
            color=DESIGN_COLOURS.get(choice.design, "0.5"),
            ls="-" if blind else "--",
            lw=2.0 if blind else 1.4,
            marker="o" if blind else ".",
            ms=4,
            label=f"{DESIGN_LABELS.get(choice.design, choice.design)}: {choice.method}",
        )
    ax.set_xlabel("screen depth z (mm)")
    ax.set_ylabel(METRIC_LABELS.get(metric, metric))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="best")
    ax.set_title(
        f"Each design with its best blind (solid) and non-blind (dashed) compensation: "
        f"{METRIC_LABELS.get(metric, metric)}",
        fontsize=10,
    )
    _save(fig, path)


def _tile_text(scores: dict, best: dict) -> list[tuple[str, bool]]:
    parts = []
    for metric, short, fmt in TILE_METRICS:
        if metric in scores:
            parts.append((f"{short} {fmt.format(scores[metric])}", scores[metric] == best.get(metric)))
    return parts


def _best_of(row_scores: Sequence[dict]) -> dict:
    best: dict = {}
    for scores in row_scores:
        for metric, value in scores.items():
            if metric not in best or better(metric, value, best[metric]):
                best[metric] = value
    return best


def _annotate(ax, parts: list[tuple[str, bool]]) -> None:
    y = 0.02
    for text, is_best in reversed(parts):
        ax.text(
            0.02,
            y,
            text,
            transform=ax.transAxes,
            fontsize=TILE_FONT_PT,
            va="bottom",
            ha="left",
            color="red" if is_best else "white",
            fontweight="bold" if is_best else "normal",
            bbox=dict(facecolor="white" if is_best else "black", alpha=0.8 if is_best else 0.55, pad=1.0, lw=0),
        )
        y += 0.15


def grid_shape(n_cells: int) -> tuple[int, int]:
    """``(lines, columns)`` of ``n_cells`` tiles wrapped after :data:`GRID_MAX_COLUMNS` in balanced
    lines (9 tiles as 3 x 3, not 4 + 4 + 1)."""
    lines = -(-n_cells // GRID_MAX_COLUMNS)
    return lines, -(-n_cells // lines)


def _image_grid(
    rows: Sequence[tuple[str, np.ndarray | None, Sequence[tuple[str, np.ndarray, dict]]]], path, title: str
) -> None:
    """``rows``: ``(row label, target or None, [(method, display, scores)])``. Each row's tiles (the
    target first, when given) wrap after :data:`GRID_MAX_COLUMNS`, so that the figure stays readable at
    page width; every tile carries its method's name."""
    n_cells = max((r[1] is not None) + len(r[2]) for r in rows)
    lines_per_row, n_cols = grid_shape(n_cells)
    first = rows[0][1] if rows[0][1] is not None else rows[0][2][0][1]
    height, width = first.shape[:2]
    tile = GRID_TILE_IN
    n_lines = len(rows) * lines_per_row
    fig_height_in = (tile * height / width + 0.35) * n_lines + 0.7
    fig, axes = plt.subplots(n_lines, n_cols, figsize=(tile * n_cols, fig_height_in), squeeze=False)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for r, (label, target, tiles) in enumerate(rows):
        best = _best_of([scores for _, _, scores in tiles])
        cells = ([("target", target, None)] if target is not None else []) + list(tiles)
        for index in range(lines_per_row * n_cols):
            ax = axes[r * lines_per_row + index // n_cols, index % n_cols]
            if index >= len(cells):
                ax.axis("off")
                continue
            method, image, scores = cells[index]
            ax.imshow(np.clip(image, 0, 1))
            bold = "bold" if method == "doe+net" else "normal"
            ax.set_title(method, fontsize=TILE_FONT_PT + 1, fontweight=bold, pad=3)
            if index % n_cols == 0:
                ax.set_ylabel(label, fontsize=TILE_FONT_PT + 1)
            if scores is not None:
                _annotate(ax, _tile_text(scores, best))
    fig.suptitle(title, fontsize=TILE_FONT_PT + 1)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.45 / fig_height_in))  # room for the title
    _save(fig, path, dpi=GRID_DPI)


def plot_comparison(
    target: np.ndarray,
    examples: dict,
    depths_mm: Sequence[float],
    methods: Sequence[str],
    path: str | Path,
    image_name: str = "",
) -> None:
    """Paper Fig. 6: rows = ``depths_mm``, columns = target + ``methods``; ``examples`` from
    :func:`edofproj.evaluation.sweep.example_displays`."""
    rows = []
    for z in depths_mm:
        tiles = [(m, *examples[(float(z), m)]) for m in methods if (float(z), m) in examples]
        rows.append((f"z = {z:.0f} mm", target, tiles))
    has_lpips = any("lpips" in scores for _, _, row in rows for _, _, scores in row)
    legend = "P = PSNR dB, S = SSIM" + (", L = LPIPS" if has_lpips else "")
    _image_grid(
        rows,
        path,
        f"Simulated projections{' of ' + image_name if image_name else ''} ({legend}; best of each row in red)",
    )


def plot_captured_comparison(
    rows: Sequence[tuple[str, np.ndarray, list[tuple[str, np.ndarray, dict]]]], path: str | Path
) -> None:
    """Real captures side by side (paper Table 2's images): one row per target image
    ``(name, target, [(method, rectified capture, scores)])``, the target first."""
    _image_grid(
        list(rows), path, "Captured projections in projector space (P = PSNR dB, S = SSIM; best of each row in red)"
    )


def plot_tilted(
    target: np.ndarray,
    examples: dict,
    methods: Sequence[str],
    path: str | Path,
    near_mm: float,
    far_mm: float,
    tilt_deg: float,
) -> None:
    """The tilted screen: target + one tile per method (near edge on the left)."""
    tiles = [(m, *examples[m]) for m in methods if m in examples]
    label = f"{near_mm:.0f} mm (left) to\n{far_mm:.0f} mm (right)"
    _image_grid(
        [(label, target, tiles)],
        path,
        f"Tilted screen ({tilt_deg:g} deg, depth {near_mm:.0f}-{far_mm:.0f} mm; P = PSNR, S = SSIM)",
    )


def _smoothed(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(steps, loss, smooth steps, smooth loss)``: the moving average over 1/20 of the run."""
    steps = np.array([r["step"] for r in rows], dtype=float)
    loss = np.array([r["loss"] for r in rows], dtype=float)
    width = max(1, len(loss) // 20)
    smooth = np.convolve(loss, np.ones(width) / width, mode="valid") if len(loss) >= width else loss
    return steps, loss, steps[len(steps) - len(smooth) :], smooth


def plot_training_curves(curves: Sequence[tuple[str, list[dict]]], path: str | Path) -> None:
    """Training loss (moving average over 1/20 of the run) against step: one panel per run, so that
    no curve hides another (runs of the same data and seed can coincide step for step); each panel
    shows its run in colour over the other runs in grey, on shared axes."""
    curves = [(label, rows) for label, rows in curves if rows]
    if not curves:
        return
    n_cols = min(len(curves), 3)
    n_rows = -(-len(curves) // n_cols)
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(3.6 * n_cols, 2.6 * n_rows + 0.6), sharex=True, sharey=True, squeeze=False
    )
    smoothed = [(label, *_smoothed(rows)) for label, rows in curves]
    for index, (label, steps, loss, smooth_steps, smooth) in enumerate(smoothed):
        ax = axes[index // n_cols, index % n_cols]
        for other, _, _, other_steps, other_smooth in smoothed:
            if other != label:
                ax.plot(other_steps, other_smooth, color="0.75", lw=0.9)
        style = _method_style(index, label)
        style.pop("marker", None)
        style["ls"] = "-"
        ax.plot(steps, loss, color=style["color"], alpha=0.2, lw=0.6)
        ax.plot(smooth_steps, smooth, **style)
        ax.set_title(label, fontsize=10, fontweight="bold" if label == "doe+net" else "normal")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        if index % n_cols == 0:
            ax.set_ylabel("training loss")
        if index // n_cols == n_rows - 1 or index + n_cols >= len(smoothed):
            ax.set_xlabel("step")
    for index in range(len(smoothed), n_rows * n_cols):
        axes[index // n_cols, index % n_cols].axis("off")
    fig.suptitle(
        "Training loss (alpha MSE + beta perceptual) of each run: moving average, faint per step; grey: the other runs",
        fontsize=10,
    )
    fig.tight_layout()
    _save(fig, path)


def plot_scene_grid(
    targets: dict, examples: dict, scenes: Sequence[str], methods: Sequence[str], path: str | Path
) -> None:
    """Rows = scenes, columns = the target on the object and each method's display (PSNR/SSIM over the
    object's pixels on each tile); ``examples[(scene, method)] = (display, ssim map, scores)``."""
    rows = []
    for scene in scenes:
        tiles = [(m, examples[(scene, m)][0], examples[(scene, m)][2]) for m in methods if (scene, m) in examples]
        rows.append((scene, targets[scene], tiles))
    _image_grid(rows, path, "Projection onto scenes (P = PSNR dB, S = SSIM over the object's pixels; best in red)")


def plot_scene_ssim_maps(examples: dict, scenes: Sequence[str], methods: Sequence[str], path: str | Path) -> None:
    """Local SSIM (0 black to 1 white, grey off the object), a row of tiles per scene (wrapped as
    :func:`_image_grid` wraps), each tile's SSIM over the object written on it."""
    rows = []
    for scene in scenes:
        tiles = []
        for method in methods:
            if (scene, method) in examples:
                _, local, scores = examples[(scene, method)]
                grey = np.where(np.isfinite(local), np.clip(local, 0.0, 1.0), 0.5)
                tiles.append((method, np.repeat(grey[..., None], 3, axis=-1), {"ssim": scores["ssim"]}))
        if tiles:
            rows.append((scene, None, tiles))
    if rows:
        _image_grid(
            rows, path, "Local SSIM on the objects (white = 1, grey: off the object; S = mean SSIM, best in red)"
        )
