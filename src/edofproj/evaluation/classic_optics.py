"""Classic EDOF elements tuned for a projector and a depth range, each by its best blind linear filter.

A classic element (a cubic phase plate, an axicon, multifocal zones; :mod:`edofproj.doe.designs`)
has free parameters: the cubic strength ``alpha`` (waves), the axicon's focal-line ends, the
multifocal foci. A fair comparison with a learned DOE gives each element the parameters that suit
*this* projector (the configuration's optics and spectrum) and *this* range. Each candidate is
scored by what a projector that does not know its screen's depth could do with it: its blind
method ``X+ensemble`` (:mod:`edofproj.methods.compensators`), the depth-ensemble Wiener filter of
the candidate's PSFs over the scored range, NSR tuned on *training* crops,

    x = clamp(g_X * I, 0, 1),      score(X) = mean_z mean_images SSIM( project(x, p_z^X), I )

on the *validation* images (:mod:`edofproj.data.validation`; never the test images) at the sweep's
depths; the worst depth is reported beside the mean. The chosen candidate has the highest mean
(ties: the higher worst depth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..config import Config, apply_overrides
from ..data.validation import validation_images
from ..errors import EdofprojError
from ..methods.builder import MethodBuilder
from ..methods.catalogue import CLASSIC_ELEMENTS, method_spec
from ..progress import StageProgress
from .results import MetricsTable
from .sweep import flat_screen_sweep

#: Candidates swept when none are given: around and beyond the values the presets started from.
DEFAULT_CANDIDATES = {
    "cubic": "2.5,5,7.5,10,15,20,40",
    "axicon": "200:1000,250:900,300:800,350:700,400:600",
    "multifocal": "350/500/700;300/450/800;320/420/550/750;300/380/480/620/800",
}
#: What a candidate's text means, per element.
CANDIDATE_SYNTAX = {
    "cubic": "alpha in waves, comma-separated (e.g. 5,10,20)",
    "axicon": "focal-line ends NEAR:FAR in mm, comma-separated (e.g. 300:800,250:900)",
    "multifocal": "foci in mm joined by '/', candidates separated by ';' (e.g. 350/500/700;300/450/800)",
}


@dataclass(frozen=True)
class Candidate:
    """One parameter choice: its label for tables and plots, its value on the plot's axis, the config overrides."""

    label: str
    value: float
    overrides: tuple[str, ...]


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise EdofprojError(f"{what}: '{text}' is not a number") from None
    if not math.isfinite(value):
        raise EdofprojError(f"{what}: '{text}' is not finite")
    return value


def parse_candidates(kind: str, text: str) -> list[Candidate]:
    """The candidates of ``text`` (:data:`CANDIDATE_SYNTAX`) for the element ``kind``; one-line errors."""
    if kind not in CLASSIC_ELEMENTS:
        raise EdofprojError(f"unknown classic element '{kind}' (known: {', '.join(CLASSIC_ELEMENTS)})")
    what = f"--values for {kind} ({CANDIDATE_SYNTAX[kind]})"
    separator = ";" if kind == "multifocal" else ","
    items = [item.strip() for item in text.split(separator) if item.strip()]
    if not items:
        raise EdofprojError(f"{what}: no candidate given")
    candidates = []
    for item in items:
        if kind == "cubic":
            alpha = _number(item, what)
            if alpha <= 0:
                raise EdofprojError(f"{what}: alpha {item} must be > 0")
            candidates.append(Candidate(f"{alpha:g} waves", alpha, (f"doe.cubic_waves={alpha:g}",)))
        elif kind == "axicon":
            near_text, _, far_text = item.partition(":")
            near, far = _number(near_text, what), _number(far_text, what)
            if not 0 < near < far:
                raise EdofprojError(f"{what}: '{item}' needs 0 < near < far")
            candidates.append(
                Candidate(
                    f"{near:g}-{far:g} mm", far - near, (f"doe.axicon_near_mm={near:g}", f"doe.axicon_far_mm={far:g}")
                )
            )
        else:
            foci = [_number(f, what) for f in item.split("/") if f.strip()]
            if not foci or any(f <= 0 for f in foci):
                raise EdofprojError(f"{what}: '{item}' needs positive foci")
            listed = ",".join(f"{f:g}" for f in foci)
            candidates.append(
                Candidate(
                    "/".join(f"{f:g}" for f in foci) + " mm", float(len(foci)), (f"doe.multifocal_foci_mm=[{listed}]",)
                )
            )
    if len({c.label for c in candidates}) != len(candidates):
        raise EdofprojError(f"{what}: a candidate is given twice")
    return candidates


@dataclass
class ClassicSweep:
    """Scores of every candidate: ``table`` rows (candidate, depth_mm, image) with ``ssim`` and ``psnr``;
    ``nsr`` the tuned NSR of each candidate's filter; ``summary`` per candidate ``(mean, worst, worst depth)``."""

    kind: str
    candidates: list[Candidate]
    depths_mm: list[float]
    image_names: list[str]
    table: MetricsTable
    nsr: dict[str, float] = field(default_factory=dict)
    summary: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    baseline_label: str | None = None

    @property
    def chosen_at_edge(self) -> bool:
        """Whether the chosen candidate has the smallest or the largest parameter value of the sweep
        (with more than two candidates): the optimum may lie outside the swept range."""
        values = [c.value for c in self.candidates]
        return len(set(values)) > 2 and self.chosen.value in (min(values), max(values))

    @property
    def chosen(self) -> Candidate:
        """The candidate with the highest mean SSIM (ties: the higher worst-depth SSIM)."""
        return max(self.candidates, key=lambda c: (self.summary[c.label][0], self.summary[c.label][1]))


def summarize(table: MetricsTable, labels: Sequence[str], depths_mm: Sequence[float]) -> dict:
    """Per candidate: the mean over the depths of the image-mean SSIM, the worst such depth and its SSIM."""
    summary = {}
    for label in labels:
        per_depth = []
        for depth in depths_mm:
            values = [r["ssim"] for r in table.rows if r["candidate"] == label and r["depth_mm"] == float(depth)]
            per_depth.append(float(np.mean(values)))
        worst = int(np.argmin(per_depth))
        summary[label] = (float(np.mean(per_depth)), per_depth[worst], float(depths_mm[worst]))
    return summary


def sweep_classic_element(
    cfg: Config,
    kind: str,
    candidates: Sequence[Candidate],
    depths_mm: Sequence[float],
    progress: StageProgress | None = None,
    max_images: int = 0,
) -> ClassicSweep:
    """Score every candidate of the element ``kind`` by ``kind+ensemble`` on the validation images
    (module docstring). ``cfg``: the projector, spectrum, PSF sampling and scored range
    (``evaluation.score_range_mm``) the element is tuned for; ``max_images`` > 0 keeps the first ones."""
    depths = sorted({float(z) for z in depths_mm})
    if not depths or any(not (math.isfinite(z) and z > 0) for z in depths):
        raise EdofprojError(f"--depths-mm needs positive depths, got {list(depths_mm)}")
    size = cfg.evaluation.image_size
    images = validation_images((int(size[0]), int(size[1])) if size else None, cfg.evaluation.image_scaling, max_images)
    spec = method_spec(f"{kind}+ensemble")
    progress = progress or StageProgress("tune-classic", enabled=False)
    table = MetricsTable(("candidate", "depth_mm", "image"), ("ssim", "psnr"))
    sweep = ClassicSweep(kind, list(candidates), depths, [name for name, _ in images], table)
    progress.start("candidates", len(candidates) * len(depths) * len(images), detail=f"{kind}: {len(candidates)}")
    for candidate in candidates:
        candidate_cfg = apply_overrides(cfg, list(candidate.overrides))
        builder = MethodBuilder(None, candidate_cfg, Path("."), explicit=True)  # no separate run is needed
        method = builder.build(spec)
        if method is None:  # explicit: a classic element needs no separate run
            raise EdofprojError(f"{spec.name} could not be built")
        sweep.nsr[candidate.label] = builder.nsr[f"{kind}+ensemble"]
        scores = flat_screen_sweep([method], images, depths, {}, progress=progress.advance)
        for row in scores.rows:
            table.add(
                candidate=candidate.label,
                depth_mm=row["depth_mm"],
                image=row["image"],
                ssim=row["ssim"],
                psnr=row["psnr"],
            )
    progress.finish()
    sweep.summary = summarize(table, [c.label for c in candidates], depths)
    return sweep


def current_candidate(cfg: Config, kind: str) -> str:
    """The label of the configuration's own parameters for ``kind`` (what the presets use today)."""
    doe = cfg.doe
    if kind == "cubic":
        return f"{doe.cubic_waves:g} waves"
    if kind == "axicon":
        return f"{doe.axicon_near_mm:g}-{doe.axicon_far_mm:g} mm"
    return "/".join(f"{f:g}" for f in doe.multifocal_foci_mm) + " mm"
