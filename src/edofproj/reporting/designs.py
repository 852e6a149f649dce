"""Each optical design at its best: its best blind and its best non-blind compensation.

The comparison an optics reviewer asks for: not one method per design, but every design (the bare
lens, the learned DOE, the classic elements) with the best compensation the evaluation scored for it,
blind and non-blind apart (:attr:`~edofproj.methods.catalogue.MethodSpec.blind`). Best means the highest
mean over the scored depth range ``Z`` of the per-depth means over the images,

    best(d, kind) = argmax_{m in M(d, kind)} (1/|Z|) sum_{z in Z} SSIM_m(z)

where ``M(d, kind)`` are the evaluated methods of design ``d``
(:attr:`~edofproj.methods.catalogue.MethodSpec.design`) that are blind (or non-blind). The figure
(:func:`~edofproj.reporting.figures.plot_designs_vs_depth`) draws each chosen method's SSIM against depth,
one colour per design, solid for blind and dashed for non-blind; :func:`designs_caption` names them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..evaluation.results import MetricsTable
from ..methods.catalogue import CLASSIC_ELEMENTS, METHOD_NAMES, method_spec

#: The designs in the order the figure and the caption take them.
DESIGN_ORDER = ("lens", "doe", *CLASSIC_ELEMENTS)
#: How the caption names each design.
DESIGN_LABELS = {
    "lens": "bare lens",
    "doe": "learned DOE",
    "cubic": "cubic phase plate",
    "axicon": "axicon",
    "multifocal": "multifocal zones",
}
#: The two kinds of compensation, in the order they are drawn.
KINDS = ("blind", "non-blind")


@dataclass(frozen=True)
class DesignBest:
    """The best method of one design and kind: its name and its mean ``metric`` over the scored range."""

    design: str
    kind: str
    method: str
    mean: float


def best_compensations(table: MetricsTable, range_mm: tuple[float, float], metric: str = "ssim") -> list[DesignBest]:
    """The best blind and the best non-blind method of every design that ``table`` scores (module
    docstring), in :data:`DESIGN_ORDER` then :data:`KINDS`; a design or kind without an evaluated method is
    absent. Ties go to the method listed first in the catalogue."""
    lo_mm, hi_mm = range_mm
    best: dict[tuple[str, str], DesignBest] = {}
    for name in (n for n in METHOD_NAMES if n in table.methods()):
        spec = method_spec(name)
        mean = table.range_stats(name, metric, lo_mm, hi_mm).mean
        if math.isnan(mean):
            continue
        key = (spec.design, "blind" if spec.blind else "non-blind")
        if key not in best or mean > best[key].mean:
            best[key] = DesignBest(spec.design, key[1], name, mean)
    return [best[(d, k)] for d in DESIGN_ORDER for k in KINDS if (d, k) in best]


def designs_caption(best: list[DesignBest], range_mm: tuple[float, float], metric: str = "SSIM") -> str:
    """The figure's caption: what it shows, then for each design its best blind and non-blind method
    with its mean over the scored range."""
    lo_mm, hi_mm = range_mm
    parts = []
    for design in DESIGN_ORDER:
        chosen = [b for b in best if b.design == design]
        if not chosen:
            continue
        named = ", ".join(f"`{b.method}` ({b.kind}, {b.mean:.3f})" for b in chosen)
        missing = [k for k in KINDS if k not in {b.kind for b in chosen}]
        if missing:
            named += f", no {missing[0]} method evaluated"
        parts.append(f"{DESIGN_LABELS[design]}: {named}")
    return (
        f"{metric} against screen depth of every optical design with its best blind (solid) and its best "
        f"non-blind (dashed) compensation among the evaluated methods, one colour per design; best = the highest "
        f"mean {metric} over {lo_mm:.0f}-{hi_mm:.0f} mm (shaded), given in brackets. " + "; ".join(parts) + "."
    )
