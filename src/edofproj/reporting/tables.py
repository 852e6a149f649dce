"""Summary tables of an evaluation (report blocks and plain text for the terminal).

* :func:`range_table` -- one row per method: mean and worst (with its depth) over the training
  depth range of each metric (the headline table);
* :func:`depth_table` -- one metric, one row per method, one column per depth, plus the mean
  and worst over the range;
* :func:`tilted_table` -- the tilted screen, mean over the images per method;
* :func:`image_spread_table` -- how much the images disagree: mean ± standard deviation over the
  images, the lowest image, the paired difference to a reference method;
* :func:`run_spread_table` -- several evaluations of the same methods (e.g. training seeds):
  mean ± standard deviation over the runs (:func:`check_like_runs` first: ``edofproj summarize``);
* :func:`format_text_table` -- any :class:`~edofproj.reporting.document.Table` as aligned text.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from ..errors import EdofprojError
from ..evaluation.results import (
    HIGHER_IS_BETTER,
    METRIC_LABELS,
    METRIC_RANGES,
    MetricsTable,
    better,
    format_span_mm,
    headline_metrics,
    valid_score,
)
from ..methods.catalogue import METHOD_NAMES, method_spec
from .document import Table


def _fmt(metric: str, value: float) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "NA"
    return f"{value:.2f}" if metric in ("psnr", "de2000", "de2000_p95") else f"{value:.4f}"


def _bold_best(metric: str, values: list[float]) -> list[bool]:
    finite = [v for v in values if not math.isnan(v)]
    if not finite:
        return [False] * len(values)
    best = max(finite) if HIGHER_IS_BETTER[metric] else min(finite)
    return [v == best for v in values]


def _cells(metric: str, values: list[float], extra: list[str] | None = None) -> list[str]:
    bold = _bold_best(metric, values)
    cells = [f"**{_fmt(metric, v)}**" if b else _fmt(metric, v) for v, b in zip(values, bold)]
    if extra:
        cells = [f"{c} {e}" for c, e in zip(cells, extra)]
    return cells


def method_kind(name: str) -> str:
    """``"blind"`` or ``"non-blind"`` for a method name (:attr:`MethodSpec.blind`); ``""`` if unknown."""
    if name not in METHOD_NAMES:
        return ""
    return "blind" if method_spec(name).blind else "non-blind"


def grouped_methods(methods: Sequence[str]) -> list[str]:
    """``methods`` with the blind ones first, then the non-blind ones (order kept within each)."""
    order = {"blind": 0, "non-blind": 1, "": 2}
    return sorted(methods, key=lambda m: order[method_kind(m)])


def range_table(
    table: MetricsTable,
    range_mm: tuple[float, float],
    metrics: Sequence[str] | None = None,
    frame_ms: dict[str, float] | None = None,
    frame_ms_note: str = "",
) -> Table:
    """Rows = methods, blind ones first; columns = what the method knows at run time, the mean and
    worst depth of each metric over ``range_mm`` (the best of each group in bold) and, with
    ``frame_ms``, the milliseconds per compensated frame (``frame_ms_note``, what they measure, ends
    the caption)."""
    metrics = list(metrics or headline_metrics(table.metrics))
    methods = grouped_methods(table.methods())
    kinds = [method_kind(m) for m in methods]
    groups = {kind: [i for i, k in enumerate(kinds) if k == kind] for kind in dict.fromkeys(kinds)}
    lo, hi = range_mm
    columns: list[list[str]] = []
    header = ["method", "knows"]
    for metric in metrics:
        stats = [table.range_stats(m, metric, lo, hi) for m in methods]
        label = METRIC_LABELS.get(metric, metric)
        header += [f"mean {label}", f"worst {label} (depth)"]
        columns.append(_grouped_cells(metric, [s.mean for s in stats], groups))
        columns.append(
            _grouped_cells(
                metric,
                [s.worst for s in stats],
                groups,
                [f"({s.worst_depth_mm:.0f})" if s.depths else "" for s in stats],
            )
        )
    if frame_ms:
        header.append("ms/frame")
        columns.append([_fmt_ms(frame_ms.get(m, math.nan)) for m in methods])
    knows = {"blind": "blind", "non-blind": "PSF of each depth", "": ""}
    rows = [[method, knows[kinds[i]]] + [col[i] for col in columns] for i, method in enumerate(methods)]
    return Table(
        header,
        rows,
        f"Mean and worst depth over {format_span_mm(lo, hi)} mm (per-depth means over the test "
        f"images; worst = lowest, or highest for LPIPS/DISTS). Blind methods know nothing of the depth "
        f"or the PSF at run time; non-blind ones are given the exact PSF of each depth. Best of each "
        f"group in bold." + (f" {frame_ms_note}." if frame_ms and frame_ms_note else ""),
    )


def _grouped_cells(
    metric: str, values: list[float], groups: dict[str, list[int]], extra: list[str] | None = None
) -> list[str]:
    cells = [""] * len(values)
    for indices in groups.values():
        part = _cells(metric, [values[i] for i in indices], [extra[i] for i in indices] if extra else None)
        for i, cell in zip(indices, part):
            cells[i] = cell
    return cells


def _fmt_ms(ms: float) -> str:
    if math.isnan(ms):
        return "-"
    return f"{ms:.2f}" if ms < 10 else f"{ms:.1f}" if ms < 100 else f"{ms:.0f}"


def image_spread_table(
    table: MetricsTable, range_mm: tuple[float, float], metric: str = "ssim", reference: str = "doe+net"
) -> Table:
    """How much the images disagree: per method, the mean over ``range_mm`` of each image
    ``m_i``, summarized as mean ± sample standard deviation over the images, the lowest image,
    and (against ``reference``) the mean ± standard deviation of the per-image difference
    ``m_i(reference) - m_i(method)`` with the number of images where the reference is better."""
    lo, hi = range_mm
    methods = grouped_methods(table.methods())
    per_image = {m: table.per_image_range_means(m, metric, lo, hi) for m in methods}
    label = METRIC_LABELS.get(metric, metric)
    rows = []
    for method in methods:
        values = per_image[method]
        if not values:
            continue
        array = np.array(list(values.values()))
        lowest = min(values, key=values.__getitem__)
        cells = [method, f"{array.mean():.4f} ± {_std(array):.4f}", f"{values[lowest]:.4f} ({lowest})"]
        ref = per_image.get(reference, {})
        shared = [i for i in values if i in ref]
        if method != reference and shared:
            diff = np.array([ref[i] - values[i] for i in shared])
            cells.append(f"{diff.mean():+.4f} ± {_std(diff):.4f} ({_count_better(metric, diff)}/{len(shared)})")
        else:
            cells.append("")
        rows.append(cells)
    return Table(
        ["method", f"mean {label} ± sd over images", "lowest image", f"{reference} minus method (images better)"],
        rows,
        f"{label} per image (mean over {format_span_mm(lo, hi)} mm), spread over the images: sample standard deviation",
    )


def run_spread_table(
    tables: Mapping[str, MetricsTable],
    range_mm: tuple[float, float],
    metric: str = "ssim",
    reference: str = "doe+net",
) -> Table:
    """How much runs disagree (e.g. training seeds, each evaluated on the same images and depths).

    For each run ``k`` and method, ``mean_k`` and ``worst_k`` are the mean and the worst over the
    depths in ``range_mm`` of the per-depth mean over the images (:meth:`MetricsTable.range_stats`).
    A row gives, over the runs that scored the method, ``mean ± sd`` of ``mean_k`` and of
    ``worst_k`` (sample standard deviation), and the paired differences ``mean_k(reference) -
    mean_k(method)`` and ``worst_k(reference) - worst_k(method)`` as mean ± sd with the number of
    runs where ``reference`` is better."""
    lo, hi = range_mm
    methods = grouped_methods(list(dict.fromkeys(m for table in tables.values() for m in table.methods())))
    stats = {(run, m): table.range_stats(m, metric, lo, hi) for run, table in tables.items() for m in table.methods()}
    label = METRIC_LABELS.get(metric, metric)
    rows = []
    for method in methods:
        runs = [run for run in tables if (run, method) in stats]
        means = np.array([stats[(run, method)].mean for run in runs])
        worsts = np.array([stats[(run, method)].worst for run in runs])
        cells = [method, method_kind(method), str(len(runs))]
        cells += [_mean_sd(means), _mean_sd(worsts)]
        shared = [run for run in runs if (run, reference) in stats]
        for column in ("mean", "worst"):
            if method != reference and shared:
                diff = np.array(
                    [getattr(stats[(run, reference)], column) - getattr(stats[(run, method)], column) for run in shared]
                )
                cells.append(f"{_mean_sd(diff, sign=True)} ({_count_better(metric, diff)}/{len(shared)})")
            else:
                cells.append("")
        rows.append(cells)
    return Table(
        [
            "method",
            "knows",
            "runs",
            f"mean {label} ± sd over runs",
            "worst depth ± sd over runs",
            f"{reference} minus method: mean (runs better)",
            f"{reference} minus method: worst depth (runs better)",
        ],
        rows,
        f"{label} over {format_span_mm(lo, hi)} mm, spread over {len(tables)} runs: sample standard deviation",
    )


def check_like_runs(
    tables: Mapping[str, MetricsTable], range_mm: tuple[float, float], metric: str, reference: str
) -> None:
    """Raise one line unless the evaluations ``tables`` (``{file: table}``) can be summarized
    together by :func:`run_spread_table`: each scores ``metric`` for every method at every one of
    its depths in ``range_mm`` and on every one of its images (a file cut short lacks rows), with no
    NaN there; all score the same images and the same depths in the range; ``reference`` is one
    of their methods."""
    lo, hi = range_mm
    first_name, first_grid = None, None
    for name, table in tables.items():
        if metric not in table.metrics:
            raise EdofprojError(f"'{name}' has no {metric} column (it has {', '.join(table.metrics)})")
        rows = [r for r in table.rows if lo - 1e-9 <= float(r["depth_mm"]) <= hi + 1e-9]
        depths = sorted({round(float(r["depth_mm"]), 6) for r in rows})
        if not depths:
            raise EdofprojError(f"'{name}' has no depth within {lo:g}-{hi:g} mm")
        images = sorted({str(r["image"]) for r in rows})
        for method in table.methods():
            cells = {(round(float(r["depth_mm"]), 6), str(r["image"])) for r in rows if r["method"] == method}
            if cells and len(cells) != len(depths) * len(images):
                raise EdofprojError(
                    f"'{name}' lacks {len(depths) * len(images) - len(cells)} of the {len(depths) * len(images)} "
                    f"scores of {method} within {lo:g}-{hi:g} mm (a truncated or edited file?)"
                )
            if any(r["method"] == method and math.isnan(float(r[metric])) for r in rows):
                raise EdofprojError(f"'{name}' has no {metric} score (NA) for {method}: choose another --metric")
            bad = [
                float(r[metric]) for r in rows if r["method"] == method and not valid_score(metric, float(r[metric]))
            ]
            if bad:
                low, high = METRIC_RANGES.get(metric, (-math.inf, math.inf))
                raise EdofprojError(
                    f"'{name}' has {len(bad)} {metric} score(s) of {method} that no evaluation gives (e.g. {bad[0]:g}; "
                    f"a score is finite and in [{low:g}, {high:g}]): an edited or damaged file?"
                )
        grid = (depths, images)
        if first_grid is not None and grid[1] != first_grid[1]:
            raise EdofprojError(f"'{name}' scores other images than '{first_name}': compare like with like")
        if first_grid is not None and grid[0] != first_grid[0]:
            raise EdofprojError(
                f"'{name}' scores other depths within {lo:g}-{hi:g} mm than '{first_name}': compare like with like"
            )
        first_name, first_grid = first_name or name, first_grid or grid
    methods = list(dict.fromkeys(m for table in tables.values() for m in table.methods()))
    if reference not in methods:
        raise EdofprojError(f"--reference '{reference}' is not a method of these evaluations ({', '.join(methods)})")


def _count_better(metric: str, reference_minus_method: np.ndarray) -> int:
    """How many of the differences ``reference - method`` favour the reference (positive where a
    higher value is better, negative for LPIPS/DISTS)."""
    return int(sum(better(metric, float(d), 0.0) for d in reference_minus_method))


def _mean_sd(values: np.ndarray, sign: bool = False) -> str:
    """``mean ± sd`` (the mean alone for one value)."""
    mean = f"{values.mean():+.4f}" if sign else f"{values.mean():.4f}"
    return f"{mean} ± {_std(values):.4f}" if values.size > 1 else mean


def _std(values: np.ndarray) -> float:
    return float(values.std(ddof=1)) if values.size > 1 else 0.0


def depth_table(table: MetricsTable, metric: str, range_mm: tuple[float, float]) -> Table:
    """One metric: rows = methods, columns = depths, mean and worst over ``range_mm``."""
    depths = table.depths_mm()
    methods = table.methods()
    lo, hi = range_mm
    label = METRIC_LABELS.get(metric, metric)
    per_method = {m: table.per_depth_means(m, metric) for m in methods}
    columns = []
    for z in depths:
        columns.append(_cells(metric, [per_method[m].get(z, math.nan) for m in methods]))
    stats = [table.range_stats(m, metric, lo, hi) for m in methods]
    columns.append(_cells(metric, [s.mean for s in stats]))
    columns.append(_cells(metric, [s.worst for s in stats]))
    header = (
        ["method"]
        + [f"{z:.0f}" for z in depths]
        + [f"mean {format_span_mm(lo, hi)}", f"worst {format_span_mm(lo, hi)}"]
    )
    rows = [[m] + [col[i] for col in columns] for i, m in enumerate(methods)]
    return Table(header, rows, f"{label} per depth (mm), mean over the test images")


def tilted_table(table: MetricsTable) -> Table:
    """Rows = methods; columns = the mean of each metric over the images on the tilted screen."""
    methods = table.methods()
    shown = headline_metrics(table.metrics)
    columns = [_cells(metric, [table.mean(metric, method=m) for m in methods]) for metric in shown]
    header = ["method"] + [METRIC_LABELS.get(m, m) for m in shown]
    rows = [[m] + [col[i] for col in columns] for i, m in enumerate(methods)]
    near, far = (table.rows[0]["near_mm"], table.rows[0]["far_mm"]) if table.rows else (math.nan, math.nan)
    return Table(header, rows, f"Tilted screen, depth {near:.0f}-{far:.0f} mm: mean over the test images")


def format_text_table(table: Table) -> str:
    """Aligned plain text (no Markdown bold markers)."""
    rows = [table.header] + [[c.replace("**", "") for c in row] for row in table.rows]
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(table.header))]
    lines = []
    for index, row in enumerate(rows):
        cells = [str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(row, widths))]
        lines.append("  ".join(cells))
        if index == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def winner(table: MetricsTable, metric: str, range_mm: tuple[float, float]) -> str | None:
    """The method with the best mean of ``metric`` over the range (None for an empty table)."""
    best, best_value = None, math.nan
    for method in table.methods():
        value = table.range_stats(method, metric, *range_mm).mean
        if not math.isnan(value) and (best is None or better(metric, value, best_value)):
            best, best_value = method, value
    return best
