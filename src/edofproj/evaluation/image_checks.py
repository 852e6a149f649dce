"""Per-image checks of an evaluation: where the network is behind its own linear filter, and where
a method loses one colour channel.

* :func:`behind_linear_filter` / :func:`behind_linear_filter_blocks` -- for every image, the mean
  over the scored depth range of the SSIM of ``doe+net`` and of ``doe+ensemble`` (the blind
  depth-ensemble linear filter of the same DOE) and their CIEDE2000 colour differences; an image
  is *flagged* where

      SSIM(doe+net) < SSIM(doe+ensemble)          (means over the scored depths)

  A trained network that is behind the fixed linear filter it could have been on some image
  is a defect to fix, not a trade-off.
* :func:`channel_imbalance_blocks` -- images where a method's per-channel SSIMs (red, green, blue,
  means over the scored depths) differ by more than :data:`CHANNEL_SPREAD` (0.05): the mark of a
  near-empty primary whose level was lost.
"""

from __future__ import annotations

from dataclasses import dataclass

from .methods import OURS
from .report import Paragraph, Table
from .results import CHANNEL_METRICS, MetricsTable

#: The blind linear baseline the network is checked against.
LINEAR_FILTER = "doe+ensemble"
#: Per-channel SSIMs that differ by more than this are reported.
CHANNEL_SPREAD = 0.05


@dataclass(frozen=True)
class ImageComparison:
    """One image: the mean SSIM and ΔE2000 over the scored depths of the network and the linear filter."""

    image: str
    ssim_net: float
    ssim_linear: float
    de_net: float
    de_linear: float

    @property
    def behind(self) -> bool:
        return self.ssim_net < self.ssim_linear


def behind_linear_filter(
    table: MetricsTable, range_mm: tuple[float, float], ours: str = OURS, linear: str = LINEAR_FILTER
) -> list[ImageComparison]:
    """One :class:`ImageComparison` per image scored by both methods ([] when either is missing)."""
    lo, hi = range_mm
    ssim_net = table.per_image_range_means(ours, "ssim", lo, hi)
    ssim_linear = table.per_image_range_means(linear, "ssim", lo, hi)
    has_de = "de2000" in table.metrics
    de_net = table.per_image_range_means(ours, "de2000", lo, hi) if has_de else {}
    de_linear = table.per_image_range_means(linear, "de2000", lo, hi) if has_de else {}
    nan = float("nan")
    return [
        ImageComparison(image, ssim_net[image], ssim_linear[image], de_net.get(image, nan), de_linear.get(image, nan))
        for image in ssim_net
        if image in ssim_linear
    ]


def behind_linear_filter_blocks(
    table: MetricsTable, range_mm: tuple[float, float], ours: str = OURS, linear: str = LINEAR_FILTER
) -> list:
    """A verdict paragraph and a per-image table (flagged images marked **behind**); [] when the
    evaluation did not score both methods."""
    rows = behind_linear_filter(table, range_mm, ours, linear)
    if not rows:
        return []
    behind = [r for r in rows if r.behind]
    lo, hi = range_mm
    if behind:
        names = ", ".join(f"{r.image} ({r.ssim_net - r.ssim_linear:+.4f})" for r in behind)
        verdict = (
            f"**{ours} is behind {linear}, its own DOE's blind linear filter, on {len(behind)} of {len(rows)} "
            f"image(s)** (mean SSIM over {lo:.0f}-{hi:.0f} mm): {names}."
        )
    else:
        verdict = f"{ours} is at least as good as {linear} on every image (mean SSIM over {lo:.0f}-{hi:.0f} mm)."
    table_rows = [
        [
            r.image,
            f"{r.ssim_net:.4f}",
            f"{r.ssim_linear:.4f}",
            f"{r.ssim_net - r.ssim_linear:+.4f}",
            f"{r.de_net:.2f}",
            f"{r.de_linear:.2f}",
            "**behind**" if r.behind else "",
        ]
        for r in rows
    ]
    header = ["image", f"SSIM {ours}", f"SSIM {linear}", "difference", f"ΔE2000 {ours}", f"ΔE2000 {linear}", ""]
    caption = f"Per image, means over {lo:.0f}-{hi:.0f} mm: the network against the linear filter of the same DOE."
    return [Paragraph(verdict), Table(header, table_rows, caption)]


def channel_imbalance_blocks(
    table: MetricsTable, range_mm: tuple[float, float], spread: float = CHANNEL_SPREAD
) -> list:
    """A table of (method, image) whose per-channel SSIMs differ by more than ``spread``, or a
    sentence saying there is none; [] when the table has no per-channel columns."""
    if not all(m in table.metrics for m in CHANNEL_METRICS):
        return []
    lo, hi = range_mm
    rows = []
    for method in table.methods():
        channels = [table.per_image_range_means(method, m, lo, hi) for m in CHANNEL_METRICS]
        for image in channels[0]:
            values = [c[image] for c in channels]
            if max(values) - min(values) > spread:
                rows.append([method, image] + [f"{v:.4f}" for v in values] + [f"{max(values) - min(values):.4f}"])
    if not rows:
        return [Paragraph(f"No method's colour channels differ in SSIM by more than {spread:g} on any image.")]
    return [
        Table(
            ["method", "image", "SSIM red", "SSIM green", "SSIM blue", "spread"],
            rows,
            f"Images where a method's per-channel SSIMs (means over {lo:.0f}-{hi:.0f} mm) differ by more than "
            f"{spread:g}: a colour channel, often a nearly empty primary, is rendered worse than the others.",
        )
    ]
