"""GDSII layout of the binary masks (gdstk): concentric annuli, one layer per mask, in micrometres.

Layout (cell ``DOE``, database unit 1 nm, user unit 1 um, centred on the optical axis):

* layer ``j + 1``: the regions etched in cycle ``j`` (mask ``j``; see :mod:`.masks`), each
  etched annulus one polygon (a disk when it starts on the axis);
* layer ``APERTURE_LAYER`` (100): the clear aperture, a disk of the aperture radius; the
  chrome stop is deposited outside it;
* with a die layout (:mod:`.layout`): the alignment marks on every mask layer, clear windows over
  them on the aperture layer, and the die outline on layer 101.

Circles are polygons whose vertices lie on the circle; the largest gap between an arc and
its chord (the sagitta) is the ``tolerance``: for a radius ``r`` and ``n`` vertices it is
``r (1 - cos(pi / n))``, so ``n ~ pi sqrt(r / (2 tolerance))`` (1300 vertices for r = 3.5 mm
at 10 nm). Polygons with more than ``MAX_POINTS`` vertices (the GDSII record limit) are split
by gdstk into pieces that tile the same region.
"""

from __future__ import annotations

from pathlib import Path

import gdstk
import numpy as np

from ..errors import EdofprojError
from .layout import DieLayout, die_outline, mark_polygons, window_polygons
from .masks import MaskLayer

APERTURE_LAYER = 100
CELL_NAME = "DOE"
UNIT_M = 1e-6
PRECISION_M = 1e-9
MAX_POINTS = 8190
MIN_TOLERANCE_UM = 0.001  # the database grid


def arc_tolerance_um(narrowest_feature_m: float, arc_tolerance_um: float = 0.01) -> float:
    """Sagitta for the polygonal circles: ``arc_tolerance_um`` and at most 1 % of the narrowest
    feature, not below the 1 nm database grid."""
    return float(max(min(arc_tolerance_um, narrowest_feature_m * 1e6 / 100), MIN_TOLERANCE_UM))


def annulus_polygon(inner_um: float, outer_um: float, tolerance_um: float, layer: int) -> gdstk.Polygon:
    """One etched annulus ``[inner, outer)`` (a disk when ``inner`` is 0) as a gdstk polygon."""
    inner = inner_um if inner_um > 0 else None
    return gdstk.ellipse((0.0, 0.0), outer_um, inner_radius=inner, tolerance=tolerance_um, layer=layer)


def build_library(
    masks: list[MaskLayer],
    aperture_radius_m: float,
    tolerance_um: float,
    name: str = "EDOFPROJ_DOE",
    layout: DieLayout | None = None,
) -> gdstk.Library:
    """A gdstk library with one cell holding all mask layers and the aperture layer (and, with ``layout``,
    the alignment marks of every layer and the die outline)."""
    lib = gdstk.Library(name, unit=UNIT_M, precision=PRECISION_M)
    cell = lib.new_cell(CELL_NAME)
    for mask in masks:
        for inner_m, outer_m in mask.annuli_m:
            cell.add(annulus_polygon(inner_m * 1e6, outer_m * 1e6, tolerance_um, mask.gds_layer))
        if layout is not None:
            cell.add(*mark_polygons(layout, mask.index, mask.gds_layer))
    cell.add(annulus_polygon(0.0, aperture_radius_m * 1e6, tolerance_um, APERTURE_LAYER))
    if layout is not None:
        cell.add(*window_polygons(layout, APERTURE_LAYER), die_outline(layout))
    return lib


def write_gds(
    path: str | Path,
    masks: list[MaskLayer],
    aperture_radius_m: float,
    tolerance_um: float,
    layout: DieLayout | None = None,
) -> dict:
    """Write the layout to ``path`` (the caller makes it atomic); returns polygon and vertex counts."""
    lib = build_library(masks, aperture_radius_m, tolerance_um, layout=layout)
    lib.write_gds(str(path), max_points=MAX_POINTS)
    cell = lib.cells[0]
    if not isinstance(cell, gdstk.Cell):
        raise EdofprojError("the GDSII layout's first cell is a raw cell, not a cell of polygons")
    polygons = cell.polygons
    return {
        "polygons": len(polygons),
        "vertices": int(sum(len(p.points) for p in polygons)),
        "tolerance_um": tolerance_um,
    }


def read_layers(path: str | Path) -> dict[int, list[gdstk.Polygon]]:
    """Polygons of a GDSII file by layer, coordinates in micrometres."""
    lib = gdstk.read_gds(str(path), unit=UNIT_M)
    layers: dict[int, list[gdstk.Polygon]] = {}
    for cell in lib.top_level():
        if not isinstance(cell, gdstk.Cell):
            raise EdofprojError(f"'{path}': top-level cell '{cell.name}' is a raw cell, not a cell of polygons")
        for polygon in cell.get_polygons():
            layers.setdefault(polygon.layer, []).append(polygon)
    return layers


def inside_layer(points_um: np.ndarray, polygons: list[gdstk.Polygon]) -> np.ndarray:
    """Point-in-polygon test (gdstk) of ``points_um`` (n, 2) against a layer's polygons."""
    if not polygons:
        return np.zeros(len(points_um), dtype=bool)
    points = np.asarray(points_um, dtype=float)
    # gdstk accepts an (n, 2) array of points; its stubs only name sequences of tuples
    return np.asarray(gdstk.inside(points, polygons), dtype=bool)  # type: ignore[arg-type]
