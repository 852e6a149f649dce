"""Per-image checks of an evaluation: where the network is behind its own linear filter, and where
a method loses one colour channel (their report sections: :mod:`edofproj.reporting.image_checks`).

* :func:`behind_linear_filter` -- for every image, the mean
  over the scored depth range of the SSIM of ``doe+net`` and of ``doe+ensemble`` (the blind
  depth-ensemble linear filter of the same DOE) and their CIEDE2000 colour differences; an image
  is *flagged* where

      SSIM(doe+net) < SSIM(doe+ensemble)          (means over the scored depths)

  A trained network that is behind the fixed linear filter it could have been on some image
  is a defect to fix, not a trade-off.
* :func:`channel_imbalances` -- images where a method's per-channel SSIMs (red, green, blue,
  means over the scored depths) differ by more than :data:`CHANNEL_SPREAD` (0.05): the mark of a
  near-empty primary whose level was lost.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..methods.catalogue import OURS
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


@dataclass(frozen=True)
class ChannelImbalance:
    """One method on one image: its per-channel SSIMs (red, green, blue; means over the scored depths)."""

    method: str
    image: str
    ssim_rgb: tuple[float, float, float]

    @property
    def spread(self) -> float:
        return max(self.ssim_rgb) - min(self.ssim_rgb)


def channel_imbalances(
    table: MetricsTable, range_mm: tuple[float, float], spread: float = CHANNEL_SPREAD
) -> list[ChannelImbalance] | None:
    """Every (method, image) whose per-channel SSIMs differ by more than ``spread``; None when the
    table has no per-channel columns."""
    if not all(m in table.metrics for m in CHANNEL_METRICS):
        return None
    lo, hi = range_mm
    found = []
    for method in table.methods():
        channels = [table.per_image_range_means(method, m, lo, hi) for m in CHANNEL_METRICS]
        for image in channels[0]:
            values = (channels[0][image], channels[1][image], channels[2][image])
            if max(values) - min(values) > spread:
                found.append(ChannelImbalance(method, image, values))
    return found
