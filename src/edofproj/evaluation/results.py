"""The metrics table of an evaluation: one row per (method, depth, image), and its statistics.

``metrics.csv`` columns: ``method,depth_mm,image,psnr,ssim,ms_ssim,de2000,de2000_p95,ssim_r,ssim_g,ssim_b``
(``de2000``/``de2000_p95``: mean and 95th percentile of the CIEDE2000 colour difference over the
pixels; ``ssim_r/g/b``: SSIM of each colour channel, :mod:`edofproj.metrics`) and, when their
weights are present on the machine, ``lpips,dists``. A perceptual metric that cannot be computed is *left
out* (never written as 0). The tilted screen has its own table (``tilted_metrics.csv``:
``method,near_mm,far_mm,image,...``).

Statistics over a depth range ``[lo, hi]`` (``evaluation.score_range_mm``: 300-800 mm for the presets):
with ``m(z)`` the mean of a metric over the images at depth ``z``,

    mean  = (1 / |Z|) sum_{z in Z} m(z),          worst = min_{z in Z} m(z)   (max for lower-is-better)

where ``Z`` are the evaluated depths inside the range.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import EdofprojError
from ..fileio import write_text_atomic
from ..methods.depth_ranges import format_span_mm  # noqa: F401 (the tables' headings use it)

#: Colour fidelity: CIEDE2000 difference, mean and 95th percentile over the pixels.
COLOUR_METRICS = ("de2000", "de2000_p95")
#: SSIM of each colour channel: detail columns, reported where a method's channels disagree.
CHANNEL_METRICS = ("ssim_r", "ssim_g", "ssim_b")
BASE_METRICS = ("psnr", "ssim", "ms_ssim") + COLOUR_METRICS + CHANNEL_METRICS
PERCEPTUAL_METRICS = ("lpips", "dists")
#: Whether a larger value is better, per metric column.
HIGHER_IS_BETTER = {
    "psnr": True,
    "ssim": True,
    "ms_ssim": True,
    "lpips": False,
    "dists": False,
    "de2000": False,
    "de2000_p95": False,
    "ssim_r": True,
    "ssim_g": True,
    "ssim_b": True,
}
METRIC_LABELS = {
    "psnr": "PSNR (dB)",
    "ssim": "SSIM",
    "ms_ssim": "MS-SSIM",
    "lpips": "LPIPS",
    "dists": "DISTS",
    "de2000": "ΔE2000",
    "de2000_p95": "ΔE2000 p95",
    "ssim_r": "SSIM red",
    "ssim_g": "SSIM green",
    "ssim_b": "SSIM blue",
}


#: The values a score can take, per metric column (finite in any case): SSIM and its variants lie in
#: [-1, 1] by definition, PSNR is any finite number of dB, the differences are >= 0.
METRIC_RANGES = {
    "psnr": (-math.inf, math.inf),
    "ssim": (-1.0, 1.0),
    "ms_ssim": (-1.0, 1.0),
    "lpips": (0.0, math.inf),
    "dists": (0.0, math.inf),
    "de2000": (0.0, math.inf),
    "de2000_p95": (0.0, math.inf),
    "ssim_r": (-1.0, 1.0),
    "ssim_g": (-1.0, 1.0),
    "ssim_b": (-1.0, 1.0),
}


def valid_score(metric: str, value: float) -> bool:
    """Whether ``value`` is a score ``metric`` can take (:data:`METRIC_RANGES`; finite; an unknown
    metric: any finite number)."""
    low, high = METRIC_RANGES.get(metric, (-math.inf, math.inf))
    return math.isfinite(value) and low <= value <= high


def headline_metrics(metrics) -> tuple[str, ...]:
    """The metrics of the summary tables and figures: all but the per-channel SSIM columns."""
    return tuple(m for m in metrics if m not in CHANNEL_METRICS)


def better(metric: str, a: float, b: float) -> bool:
    """Is value ``a`` strictly better than ``b`` for ``metric``?"""
    return a > b if HIGHER_IS_BETTER[metric] else a < b


@dataclass
class RangeStats:
    """Mean and worst of the per-depth means of one method and metric over a depth range."""

    mean: float
    worst: float
    worst_depth_mm: float
    depths: int


@dataclass
class MetricsTable:
    """Rows of ``keys`` (e.g. method, depth_mm, image) and ``metrics`` values."""

    keys: tuple[str, ...]
    metrics: tuple[str, ...]
    rows: list[dict] = field(default_factory=list)

    @property
    def columns(self) -> tuple[str, ...]:
        """The key columns followed by the metric columns, in CSV order."""
        return self.keys + self.metrics

    def add(self, **row) -> None:
        """Append a row given as ``column=value`` for every column (extra names are dropped). Raises
        ``ValueError`` naming the missing columns."""
        missing = [c for c in self.columns if c not in row]
        if missing:
            raise ValueError(f"row misses columns {missing}")
        self.rows.append({c: row[c] for c in self.columns})

    # -- selection ---------------------------------------------------------------------
    def methods(self) -> list[str]:
        """The ``method`` values, each once, in order of first appearance."""
        return list(dict.fromkeys(r["method"] for r in self.rows))

    def depths_mm(self) -> list[float]:
        """The distinct ``depth_mm`` values (mm), ascending."""
        return sorted({float(r["depth_mm"]) for r in self.rows})

    def values(self, metric: str, **where) -> np.ndarray:
        """The ``metric`` column (n,) of the rows matching every ``column=value`` of ``where``, in row order;
        strings must be equal, numbers within 1e-6 (``depth_mm=300`` matches 300.0)."""
        return np.array(
            [float(r[metric]) for r in self.rows if all(_same(r[k], v) for k, v in where.items())], dtype=float
        )

    def mean(self, metric: str, **where) -> float:
        """Mean of :meth:`values`; NaN when no row matches."""
        values = self.values(metric, **where)
        return float(values.mean()) if values.size else math.nan

    def per_depth_means(self, method: str, metric: str) -> dict[float, float]:
        """``{z: m(z)}``: the mean of ``metric`` over the images of ``method`` at each depth ``z`` (mm) where
        it has rows, depths ascending; the rows of a depth are those within 1e-6 mm of it, as :meth:`mean`
        matches them (one pass over the rows: the reports ask for every method and metric)."""
        depths = self.depths_mm()
        selected: dict[float, list[float]] = {z: [] for z in depths}
        for row in self.rows:
            if _same(row["method"], method):
                for z in depths:
                    if _same(row["depth_mm"], z):
                        selected[z].append(float(row[metric]))
        return {z: float(np.array(values, dtype=float).mean()) for z, values in selected.items() if values}

    def range_stats(self, method: str, metric: str, lo_mm: float, hi_mm: float) -> RangeStats:
        """Mean and worst of the per-depth means over the depths ``Z`` in ``[lo_mm, hi_mm]`` (module docstring:
        ``mean = (1/|Z|) sum m(z)``, worst = min, or max for a lower-is-better metric) with the worst depth
        and ``|Z|``; all NaN and 0 depths when no depth is in range."""
        means = {z: m for z, m in self.per_depth_means(method, metric).items() if lo_mm - 1e-9 <= z <= hi_mm + 1e-9}
        if not means:
            return RangeStats(math.nan, math.nan, math.nan, 0)
        pick = min if HIGHER_IS_BETTER[metric] else max
        worst_depth = pick(means, key=means.__getitem__)
        return RangeStats(float(np.mean(list(means.values()))), means[worst_depth], worst_depth, len(means))

    def per_image_range_means(self, method: str, metric: str, lo_mm: float, hi_mm: float) -> dict[str, float]:
        """``{image: mean of the metric over the depths in [lo, hi]}`` for one method."""
        values: dict[str, list[float]] = {}
        for row in self.rows:
            if row["method"] == method and lo_mm - 1e-9 <= float(row["depth_mm"]) <= hi_mm + 1e-9:
                values.setdefault(str(row["image"]), []).append(float(row[metric]))
        return {image: float(np.mean(v)) for image, v in values.items()}

    # -- files ---------------------------------------------------------------------------
    def to_csv(self) -> str:
        """The table as CSV text: a header of :attr:`columns`, then one line per row; strings as they are,
        numbers with 6 significant digits, NaN as ``NA``."""
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(self.columns)
        for row in self.rows:
            writer.writerow([_format(row[c]) for c in self.columns])
        return buffer.getvalue()

    def write_csv(self, path: str | Path) -> None:
        """:meth:`to_csv` written atomically to ``path``."""
        write_text_atomic(path, self.to_csv())

    @classmethod
    def read_csv(cls, path: str | Path, keys: tuple[str, ...]) -> "MetricsTable":
        """A table read from a CSV file whose first columns are ``keys``; the remaining columns are its
        metrics. ``method`` and ``image`` stay strings, every other column is read as a float. ``NA`` reads back
        as NaN. Raises :class:`~edofproj.errors.EdofprojError` if the file cannot be read, does not start
        with ``keys``, holds a value that is not a number or repeats a key (two rows of one method, depth
        and image)."""
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                text = handle.read()
        except OSError as exc:
            raise EdofprojError(f"cannot read metrics file '{path}': {exc.strerror or exc}") from None
        except UnicodeDecodeError:
            raise EdofprojError(f"metrics file '{path}' is not UTF-8 text (not written by edofproj)") from None
        if text and not text.endswith("\n"):  # to_csv ends every line: a file cut short ends mid-line
            raise EdofprojError(f"metrics file '{path}' is truncated (its last line is incomplete)")
        reader = csv.DictReader(io.StringIO(text, newline=""))
        header = tuple(reader.fieldnames or ())
        rows = list(reader)
        if header[: len(keys)] != keys:
            raise EdofprojError(f"'{path}' is not a metrics table (columns {', '.join(header)})")
        table = cls(keys, header[len(keys) :])
        first_line: dict[tuple, int] = {}  # each key (method, depth, image) is one score: a repeat is refused
        for line, row in enumerate(rows, start=2):
            try:
                table.rows.append({k: (row[k] if k in ("method", "image") else _number(row[k])) for k in header})
            except (TypeError, ValueError):
                raise EdofprojError(f"'{path}' line {line}: a value is not a number ({dict(row)})") from None
            key = tuple(table.rows[-1][k] for k in keys)
            if key in first_line:
                named = ", ".join(f"{k} {row[k]}" for k in keys)
                raise EdofprojError(
                    f"'{path}' line {line} repeats line {first_line[key]} ({named}): a metrics table scores each "
                    f"({', '.join(keys)}) once, and a repeat would be averaged in; remove the repeated row"
                )
            first_line[key] = line
        return table


def _number(text: str) -> float:
    """A CSV cell as a float; ``NA`` (how :meth:`MetricsTable.to_csv` writes NaN) reads back as NaN."""
    return math.nan if text == "NA" else float(text)


def _same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return abs(float(a) - float(b)) < 1e-6


def _format(value) -> str:
    if isinstance(value, str):
        return value
    value = float(value)
    return "NA" if math.isnan(value) else f"{value:.6g}"
