"""A quantized radial DOE profile as lithography sees it: rings, levels and zones.

A radial design file (:mod:`edofproj.doe.storage`) holds n rings ``[e_i, e_{i+1})`` with
one height ``h_i`` each. Quantized to ``N`` levels of step ``s = h_2pi / N``, ring i has
the integer level and height

    L_i = round(h_i / s) mod N,        h_i = L_i s,        h_2pi = lambda_d / (n(lambda_d) - 1).

Adjacent rings at the same level form a *zone*: a mask edge can only lie on a zone edge,
so the zones are the smallest features any mask can contain.

The step is also the etch depth of the shallowest mask. One below :data:`MIN_STEP_NM` is refused
(:func:`check_step`): no etch controls its depth to a nanometre (the roughness of an etched
fused-silica surface is about 1 nm RMS, and ``fabrication.etch_error_pct`` of a 100 nm etch is
3 nm), and a report of it would show masks of 0.0 nm and the ideal efficiency of ``N`` levels,
near 100 %, for a DOE that cannot be made.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..doe.quantization import quantize_levels
from ..doe.storage import TabulatedRadialDOE, load_doe
from ..errors import EdofprojError


def check_power_of_two_levels(levels: int) -> int:
    """``levels`` if it is 2^k with k >= 1 (k binary masks make 2^k levels); else a one-line error."""
    levels = int(levels)
    if levels < 2 or levels & (levels - 1):
        raise EdofprojError(
            f"levels={levels} is not a power of two: k binary masks make 2^k levels (2, 4, 8, 16, 32, ...)"
        )
    return levels


#: The shallowest etch (nm) a mask may ask for (module docstring).
MIN_STEP_NM = 1.0


def check_step(levels: int, h2pi_m: float) -> float:
    """The step ``h_2pi / N`` in metres, or one line refusing a step below :data:`MIN_STEP_NM`."""
    step_nm = h2pi_m / levels * 1e9
    if not step_nm >= MIN_STEP_NM:
        most = 1 << max(int(np.floor(np.log2(h2pi_m * 1e9 / MIN_STEP_NM))), 1)
        raise EdofprojError(
            f"{levels} levels make steps of {step_nm:.3g} nm (h_2pi {h2pi_m * 1e9:.1f} nm / {levels}), the etch depth "
            f"of the shallowest mask: below the {MIN_STEP_NM:g} nm an etch can control; at most {most} levels"
        )
    return step_nm * 1e-9


def mask_count(levels: int) -> int:
    """Number of binary masks ``k = log2(N)`` for ``N = 2^k`` levels."""
    return int(check_power_of_two_levels(levels)).bit_length() - 1


@dataclass(frozen=True)
class RadialProfile:
    """Ring edges (m, ``n + 1``) and the integer level of each ring (``n``), plus the design data."""

    ring_edges_m: np.ndarray
    level: np.ndarray
    levels: int
    h2pi_m: float
    aperture_radius_m: float
    design_wavelength_m: float
    material: str = "fused_silica"
    description: str = ""

    def __post_init__(self) -> None:
        edges = np.asarray(self.ring_edges_m, dtype=float)
        level = np.asarray(self.level, dtype=np.int64)
        if edges.ndim != 1 or level.shape != (len(edges) - 1,) or len(level) < 1:
            raise EdofprojError("a radial profile needs n + 1 ring edges and n levels (n >= 1)")
        if np.any(np.diff(edges) <= 0) or edges[0] != 0.0:
            raise EdofprojError("ring edges must start at 0 and increase strictly")
        if np.any(level < 0) or np.any(level >= self.levels):
            raise EdofprojError(f"ring levels must lie in 0..{self.levels - 1}")
        object.__setattr__(self, "ring_edges_m", edges)
        object.__setattr__(self, "level", level)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_doe(cls, doe, levels: int | None = None) -> "RadialProfile":
        """The profile of a tabulated radial DOE, quantized to ``levels`` (default: the DOE's own).

        Re-quantizing an ``N``-level design to fewer levels rounds each ring's height to the
        nearest new level (``L = round(h / s') mod N'``)."""
        if not isinstance(doe, TabulatedRadialDOE):
            raise EdofprojError(
                f"fabrication needs a radial design file (ring edges and heights); got the '{doe.name}' DOE"
            )
        n_levels = levels if levels is not None else doe.levels
        if not n_levels:
            raise EdofprojError("the design is continuous (not quantized): give the level count with --levels N")
        n_levels = check_power_of_two_levels(n_levels)
        check_step(n_levels, float(doe.h2pi_m))
        height = doe.table_height_m.detach().to(torch.float64)
        level = quantize_levels(height, doe.h2pi_m, n_levels).cpu().numpy()
        return cls(
            ring_edges_m=doe.ring_edges_m.detach().cpu().numpy().astype(float),
            level=level,
            levels=n_levels,
            h2pi_m=float(doe.h2pi_m),
            aperture_radius_m=float(doe.aperture_radius_m),
            design_wavelength_m=float(doe.design_wavelength_m),
            material=doe.material,
            description=getattr(doe, "description", doe.describe()),
        )

    @classmethod
    def from_file(cls, path: str | Path, levels: int | None = None) -> "RadialProfile":
        """Load a design file written by :func:`edofproj.doe.save_doe` (radial kind only)."""
        doe = load_doe(path)
        if not doe.radially_symmetric:
            raise EdofprojError(
                f"'{path}' holds a 2-D height map; mask export needs a radial design (ring edges and heights)"
            )
        return cls.from_doe(doe, levels)

    # ------------------------------------------------------------------ derived quantities
    @property
    def step_m(self) -> float:
        """Height of one level, ``s = h_2pi / N``."""
        return self.h2pi_m / self.levels

    @property
    def height_m(self) -> np.ndarray:
        """Height of each ring above the deepest etch floor, ``L s``."""
        return self.level * self.step_m

    @property
    def ring_centres_m(self) -> np.ndarray:
        return 0.5 * (self.ring_edges_m[1:] + self.ring_edges_m[:-1])

    def zones(self) -> tuple[np.ndarray, np.ndarray]:
        """Merge adjacent rings of equal level: zone edges (m + 1,) and zone levels (m,)."""
        change = np.nonzero(np.diff(self.level))[0] + 1  # first ring of each new zone
        starts = np.concatenate([[0], change])
        edges = np.concatenate([self.ring_edges_m[starts], self.ring_edges_m[-1:]])
        return edges, self.level[starts]

    def level_at(self, r_m) -> np.ndarray:
        """Level at radii ``r_m`` (rings are ``[e_i, e_{i+1})``; radii beyond the last edge use the last ring)."""
        idx = np.searchsorted(self.ring_edges_m[1:-1], np.asarray(r_m, dtype=float), side="right")
        return self.level[idx]

    def narrowest_zone_m(self) -> float:
        """Narrowest zone width; the central zone (a disk) counts with its diameter."""
        edges, _ = self.zones()
        widths = np.diff(edges)
        widths[0] = 2 * edges[1]
        return float(widths.min())
