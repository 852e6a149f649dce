"""The report sections of the per-image checks (:mod:`edofproj.evaluation.image_checks`): the network
against its own DOE's linear filter, and methods that lose a colour channel."""

from __future__ import annotations

from ..evaluation.image_checks import (
    CHANNEL_SPREAD,
    LINEAR_FILTER,
    behind_linear_filter,
    channel_imbalances,
)
from ..evaluation.results import MetricsTable, format_span_mm
from ..methods.catalogue import OURS
from .document import Paragraph, Table


def behind_linear_filter_blocks(
    table: MetricsTable, range_mm: tuple[float, float], ours: str = OURS, linear: str = LINEAR_FILTER
) -> list:
    """A verdict paragraph and a per-image table (its last column says whether the network is behind
    on the image); [] when the evaluation did not score both methods."""
    rows = behind_linear_filter(table, range_mm, ours, linear)
    if not rows:
        return []
    behind = [r for r in rows if r.behind]
    lo, hi = range_mm
    if behind:
        names = ", ".join(f"{r.image} ({r.ssim_net - r.ssim_linear:+.4f})" for r in behind)
        verdict = (
            f"**{ours} is behind {linear}, its own DOE's blind linear filter, on {len(behind)} of {len(rows)} "
            f"image(s)** (mean SSIM over {format_span_mm(lo, hi)} mm): {names}."
        )
    else:
        verdict = f"{ours} is at least as good as {linear} on every image (mean SSIM over {format_span_mm(lo, hi)} mm)."
    table_rows = [
        [
            r.image,
            f"{r.ssim_net:.4f}",
            f"{r.ssim_linear:.4f}",
            f"{r.ssim_net - r.ssim_linear:+.4f}",
            f"{r.de_net:.2f}",
            f"{r.de_linear:.2f}",
            "**yes**" if r.behind else "no",
        ]
        for r in rows
    ]
    header = ["image", f"SSIM {ours}", f"SSIM {linear}", "difference", f"ΔE2000 {ours}", f"ΔE2000 {linear}", "behind"]
    caption = (
        f"Per image, means over {format_span_mm(lo, hi)} mm: the network against the linear filter of the same DOE."
    )
    return [Paragraph(verdict), Table(header, table_rows, caption)]


def channel_imbalance_blocks(
    table: MetricsTable, range_mm: tuple[float, float], spread: float = CHANNEL_SPREAD
) -> list:
    """A table of (method, image) whose per-channel SSIMs differ by more than ``spread``
    (:func:`~edofproj.evaluation.image_checks.channel_imbalances`), or a sentence saying there is
    none; [] when the table has no per-channel columns."""
    found = channel_imbalances(table, range_mm, spread)
    if found is None:
        return []
    if not found:
        return [Paragraph(f"No method's colour channels differ in SSIM by more than {spread:g} on any image.")]
    lo, hi = range_mm
    rows = [[c.method, c.image] + [f"{v:.4f}" for v in c.ssim_rgb] + [f"{c.spread:.4f}"] for c in found]
    return [
        Table(
            ["method", "image", "SSIM red", "SSIM green", "SSIM blue", "spread"],
            rows,
            f"Images where a method's per-channel SSIMs (means over {format_span_mm(lo, hi)} mm) differ by more than "
            f"{spread:g}: a colour channel, often a nearly empty primary, is rendered worse than the others.",
        )
    ]
