"""Depth ranges of a run and of a sweep: which depths a table's means cover, which a run was trained on.

A run is trained on ``psf.depth_min_mm``-``psf.depth_max_mm`` (:func:`trained_range_mm`); its tables
average over the depths that lie in ``evaluation.score_range_mm`` (:func:`scored_range_mm`), and a
depth outside either is named, never silently averaged or compensated (:func:`depth_notes`).
Headings write a range as :func:`format_span_mm` does.
"""

from __future__ import annotations

from typing import Sequence


def format_span_mm(near_mm: float, far_mm: float) -> str:
    """A range of depths as headings state it: ``'300-800'``, or ``'400'`` for one depth (mm)."""
    return f"{near_mm:.0f}" if f"{near_mm:.0f}" == f"{far_mm:.0f}" else f"{near_mm:.0f}-{far_mm:.0f}"


def _within(depths_mm: Sequence[float], range_mm: tuple[float, float]) -> list[float]:
    return [float(z) for z in depths_mm if range_mm[0] - 1e-9 <= z <= range_mm[1] + 1e-9]


def scored_range_mm(depths_mm: Sequence[float], score_range_mm: tuple[float, float]) -> tuple[float, float]:
    """The depths (mm) the means and worst depths of the tables cover: those of ``depths_mm`` in
    ``score_range_mm`` (from the nearest to the farthest), or all of ``depths_mm`` when none is."""
    inside = _within(depths_mm, score_range_mm) or [float(z) for z in depths_mm]
    return min(inside), max(inside)


def trained_range_mm(cfg) -> tuple[float, float]:
    """The depths (mm) a run was trained on: ``psf.depth_min_mm``-``psf.depth_max_mm``."""
    return float(cfg.psf.depth_min_mm), float(cfg.psf.depth_max_mm)


def depth_notes(
    depths_mm: Sequence[float],
    trained_range_mm: tuple[float, float],
    score_range_mm: tuple[float, float] | None = None,
) -> list[str]:
    """Notes naming the depths asked for outside the score range (when given) and outside the trained range."""
    notes = []
    outside = [z for z in depths_mm if score_range_mm and z not in _within(depths_mm, score_range_mm)]
    if outside and score_range_mm:
        scored = scored_range_mm(depths_mm, score_range_mm)
        notes.append(
            f"depths {', '.join(f'{z:g}' for z in outside)} mm lie outside the score range "
            f"{format_span_mm(*score_range_mm)} mm (evaluation.score_range_mm): means and worst depths are over "
            f"{format_span_mm(*scored)} mm"
        )
    untrained = [z for z in depths_mm if z not in _within(depths_mm, trained_range_mm)]
    if untrained:
        notes.append(
            f"depths {', '.join(f'{z:g}' for z in untrained)} mm lie outside the range the run was trained on, "
            f"{format_span_mm(*trained_range_mm)} mm: the networks never saw their blur"
        )
    return notes
