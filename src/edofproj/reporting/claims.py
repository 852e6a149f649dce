"""The paper's claims checked by the demo, measured on held-out images (never assumed).

(a) ``doe+net`` has the best mean SSIM over the scored depth range (``evaluation.score_range_mm``) of all evaluated methods;
(b) ``doe+net``'s worst depth in that range (lowest per-depth mean SSIM) beats every other
    method's worst depth;
(c) the demo's wall time is within its budget.

A claim compares against the methods that were actually evaluated; the report lists them (a
method whose run was not trained cannot be beaten or lost to). A claim that could not be
measured (``doe+net`` missing) is reported as not measured, never as holding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..evaluation.results import MetricsTable, format_span_mm
from ..methods.catalogue import OURS


@dataclass
class Claim:
    """One claim: its statement, whether it holds (None: not measured) and the numbers behind it."""

    key: str
    statement: str
    holds: bool | None
    measured: str
    judged: bool = True

    @property
    def verdict(self) -> str:
        if not self.judged:
            return "not judged (smoke run)"
        return "not measured" if self.holds is None else ("holds" if self.holds else "does not hold")


def ssim_claims(table: MetricsTable, range_mm: tuple[float, float], metric: str = "ssim") -> list[Claim]:
    """Claims (a) and (b) on ``table`` over ``range_mm``."""
    lo, hi = range_mm
    span = f"{format_span_mm(lo, hi)} mm"
    statement_a = f"{OURS} has the best mean SSIM over {span} of all evaluated methods"
    statement_b = f"{OURS}'s worst depth in {span} beats every other method's worst depth (SSIM)"
    methods = table.methods()
    others = [m for m in methods if m != OURS]
    if OURS not in methods:
        missing = f"{OURS} was not evaluated"
        return [Claim("a", statement_a, None, missing), Claim("b", statement_b, None, missing)]
    if not others:
        alone = "no other method was evaluated"
        return [Claim("a", statement_a, None, alone), Claim("b", statement_b, None, alone)]
    stats = {m: table.range_stats(m, metric, lo, hi) for m in methods}
    ours = stats[OURS]
    if math.isnan(ours.mean):
        none = f"no {OURS} result inside {span}"
        return [Claim("a", statement_a, None, none), Claim("b", statement_b, None, none)]

    best_other_mean = max(others, key=lambda m: stats[m].mean)
    holds_a = all(ours.mean > stats[m].mean for m in others)
    measured_a = (
        f"{OURS} {ours.mean:.4f}; best other: {best_other_mean} {stats[best_other_mean].mean:.4f} "
        f"(compared: {', '.join(others)})"
    )

    best_other_worst = max(others, key=lambda m: stats[m].worst)
    holds_b = all(ours.worst > stats[m].worst for m in others)
    measured_b = (
        f"{OURS} worst {ours.worst:.4f} at {ours.worst_depth_mm:.0f} mm; best other worst: "
        f"{best_other_worst} {stats[best_other_worst].worst:.4f} at {stats[best_other_worst].worst_depth_mm:.0f} mm"
    )
    return [Claim("a", statement_a, holds_a, measured_a), Claim("b", statement_b, holds_b, measured_b)]


def wall_time_claim(seconds: float, budget_seconds: float) -> Claim:
    """Claim (c): ``seconds <= budget_seconds``."""
    return Claim(
        "c",
        f"demo wall time <= {budget_seconds / 60:.0f} min",
        seconds <= budget_seconds,
        f"{seconds / 60:.1f} min ({seconds:.0f} s)",
    )
