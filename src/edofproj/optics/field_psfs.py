"""PSFs at a grid of field points: the same DOE and depths, the lens's aberration at each point.

A :class:`~edofproj.optics.aberrations.FieldAberrations` table whose points form a full
regular grid (every ``field_x`` with every ``field_y``) gives a PSF grid
``(Gy, Gx, n_depths, C, K, K)`` ordered as rows (y, top first) by columns (x, left first),
ready for :func:`edofproj.imaging.field_varying.project_field_varying` after the field
coordinates are mapped to pixels (:func:`edofproj.imaging.field_varying.field_centres_px`).
The engine is built once; only its aberration changes between field points.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import EdofprojError
from .aberrations import FieldAberrations
from .psf_bank import PSFSimulator


def field_grid_axes(field: FieldAberrations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(xs (Gx,), ys (Gy,), index (Gy, Gx))``: the grid's axes and, per node, the point's
    position in ``field.field_xy``; refuses points that do not form a full grid."""
    xs = np.unique(field.field_xy[:, 0])
    ys = np.unique(field.field_xy[:, 1])
    index = -np.ones((len(ys), len(xs)), dtype=int)
    for p, (x, y) in enumerate(field.field_xy):
        index[np.searchsorted(ys, y), np.searchsorted(xs, x)] = p
    if np.any(index < 0) or len(field.field_xy) != index.size:
        raise EdofprojError(
            f"the aberration table's {len(field.field_xy)} field points are not a full grid "
            f"({len(xs)} x-values by {len(ys)} y-values): give every field_x with every field_y"
        )
    return xs, ys, index


def field_psf_grid(simulator: PSFSimulator, doe, depths_m, field: FieldAberrations) -> torch.Tensor:
    """RGB PSFs ``(Gy, Gx, n_depths, C, K, K)`` of ``doe`` at every field point of ``field``."""
    xs, ys, index = field_grid_axes(field)
    saved = simulator.engine.aberration
    try:
        rows = []
        for i in range(len(ys)):
            row = []
            for j in range(len(xs)):
                simulator.engine.aberration = field.pupils[index[i, j]]
                row.append(simulator(doe, depths_m))
            rows.append(torch.stack(row))
        return torch.stack(rows)
    finally:
        simulator.engine.aberration = saved
