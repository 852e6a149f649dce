"""Saving and loading DOE designs as ``.npz`` files.

A radial design is stored as its fabricated profile: ring edges ``ring_edges_m`` (n+1)
and one quantized height per ring ``height_m`` (n) with its ``level`` index. A 2-D design is
stored as ``height_map_m`` (N, N) sampled with pitch ``pitch_m`` centred on the axis.
Both carry ``levels``, ``design_wavelength_m``, ``material``, ``aperture_radius_m``,
``h2pi_m`` and a ``description``. A loaded file is a :class:`TabulatedRadialDOE` or a
:class:`TabulatedDOE2D`: the same physics, frozen.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import read_arrays, save_npz_atomic
from .base import DOE, RadialDOE, require_resolved_feature
from .quantization import quantize_levels

FORMAT = "edofproj-doe-v1"


class TabulatedRadialDOE(RadialDOE):
    """A radial profile given ring by ring (piecewise constant)."""

    name = "file"
    ring_edges_m: torch.Tensor  # buffers
    table_height_m: torch.Tensor

    def __init__(
        self,
        ring_edges_m,
        height_m,
        aperture_radius_m,
        design_wavelength_m,
        levels,
        material="fused_silica",
        description="tabulated radial DOE",
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.register_buffer("ring_edges_m", torch.as_tensor(np.asarray(ring_edges_m), dtype=torch.float64))
        self.register_buffer("table_height_m", torch.as_tensor(np.asarray(height_m), dtype=torch.float64))
        self.description = description

    def raw_height_m(self, r_m):
        edges = self.ring_edges_m.to(r_m.device)
        idx = torch.clamp(
            torch.bucketize(r_m.to(edges.dtype), edges[1:-1], right=True), 0, len(self.table_height_m) - 1
        )
        return self.table_height_m.to(r_m.device)[idx].to(r_m.dtype)

    def check_sampling(self, ring_width_m):
        finest = float(torch.min(torch.diff(self.ring_edges_m)))
        require_resolved_feature(finest, ring_width_m, self.aperture_radius_m, "the DOE file has rings")

    def describe(self):
        return f"{self.description} ({len(self.table_height_m)} rings)"


class TabulatedDOE2D(DOE):
    """A 2-D height map sampled on a square grid (nearest-neighbour lookup)."""

    name = "file"
    table_height_m: torch.Tensor  # buffer

    def __init__(
        self,
        height_map_m,
        pitch_m,
        aperture_radius_m,
        design_wavelength_m,
        levels,
        material="fused_silica",
        description="tabulated 2-D DOE",
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.register_buffer("table_height_m", torch.as_tensor(np.asarray(height_map_m), dtype=torch.float64))
        self.pitch_m = float(pitch_m)
        self.description = description

    def raw_height_map_m(self, x_m, y_m):
        n = self.table_height_m.shape[-1]
        ix = torch.clamp(torch.floor(x_m / self.pitch_m + n / 2).long(), 0, n - 1)
        iy = torch.clamp(torch.floor(y_m / self.pitch_m + n / 2).long(), 0, n - 1)
        return self.table_height_m.to(x_m.device)[iy, ix].to(x_m.dtype)

    def describe(self):
        return f"{self.description} ({self.table_height_m.shape[0]}^2 samples)"


def save_doe(doe: DOE, path: str | Path, samples: int = 1024) -> None:
    """Write the fabricated (wrapped, quantized) design of ``doe`` to ``path`` atomically.

    Radial designs are tabulated on ``samples // 2`` equal rings (sampled at ring centres,
    exactly what the radial engine simulates with ``pupil_samples = samples``); 2-D designs
    on a ``samples`` x ``samples`` grid across the aperture.
    """
    R = doe.aperture_radius_m
    common = dict(
        format=np.array(FORMAT),
        levels=np.array(doe.levels if doe.quantize else 0),
        design_wavelength_m=np.array(doe.design_wavelength_m),
        material=np.array(doe.material),
        aperture_radius_m=np.array(R),
        h2pi_m=np.array(doe.h2pi_m),
        description=np.array(doe.describe()),
    )
    with torch.no_grad():
        if isinstance(doe, RadialDOE):  # the radially symmetric DOEs
            rings = max(samples // 2, 1)
            edges = np.linspace(0.0, R, rings + 1)
            centres = torch.as_tensor(0.5 * (edges[1:] + edges[:-1]), dtype=torch.float64, device=doe.device)
            height = doe.height_m(centres).double()
            if doe.quantize:
                if doe.levels is None:
                    raise EdofprojError(f"the '{doe.name}' DOE is quantized but has no level count")
                level = quantize_levels(height, doe.h2pi_m, doe.levels)
            else:
                level = torch.zeros_like(height).long()
            save_npz_atomic(
                path,
                kind=np.array("radial"),
                ring_edges_m=edges,
                height_m=height.cpu().numpy(),
                level=level.cpu().numpy().astype(np.int32),
                **common,
            )
        else:
            pitch = 2 * R / samples
            c = (torch.arange(samples, dtype=torch.float64, device=doe.device) - samples / 2 + 0.5) * pitch
            y, x = torch.meshgrid(c, c, indexing="ij")
            height = doe.height_map_m(x, y).double()
            save_npz_atomic(
                path, kind=np.array("map"), height_map_m=height.cpu().numpy(), pitch_m=np.array(pitch), **common
            )


COMMON_KEYS = ("format", "kind", "levels", "design_wavelength_m", "material", "aperture_radius_m", "description")
KIND_KEYS = {"radial": ("ring_edges_m", "height_m"), "map": ("height_map_m", "pitch_m")}


def _scalar(data: dict[str, np.ndarray], key: str, path: Path) -> float:
    value = data[key]
    if value.size != 1 or value.dtype.kind not in "fiu":
        raise EdofprojError(f"DOE file '{path}': {key} must be one number, got shape {value.shape} ({value.dtype})")
    return float(value.reshape(-1)[0])


def validate_design(data: dict[str, np.ndarray], path: str | Path) -> None:
    """Raise a one-line error unless the arrays of a design file are a consistent design.

    Keys: :data:`COMMON_KEYS` plus, for ``kind = radial``, ``ring_edges_m (n+1)`` and
    ``height_m (n)`` (``level (n)`` when present), for ``kind = map``, ``height_map_m (N, N)``
    and ``pitch_m``. Ring edges are finite, start at ``r >= 0`` and strictly increase; heights
    are finite; the aperture radius, design wavelength and pitch are positive.
    """
    path = Path(path)
    hint = "write designs with 'edofproj train' or edofproj.doe.save_doe"
    if "format" not in data or str(data["format"]) != FORMAT:
        found = repr(str(data["format"])) if "format" in data else "no format key"
        raise EdofprojError(f"'{path}' is not an edofproj DOE file ({found}); {hint}")
    kind = str(data["kind"]) if "kind" in data else ""
    if kind not in KIND_KEYS:
        raise EdofprojError(f"DOE file '{path}' has an unknown kind {kind!r} (radial or map); {hint}")
    missing = [key for key in COMMON_KEYS + KIND_KEYS[kind] if key not in data]
    if missing:
        raise EdofprojError(f"DOE file '{path}' lacks {', '.join(missing)}; {hint}")
    for key in ("aperture_radius_m", "design_wavelength_m") + (("pitch_m",) if kind == "map" else ()):
        value = _scalar(data, key, path)
        if not (np.isfinite(value) and value > 0):
            raise EdofprojError(f"DOE file '{path}': {key} = {value:g} must be positive and finite")
    levels = _scalar(data, "levels", path)
    if levels < 0 or levels != int(levels):
        raise EdofprojError(f"DOE file '{path}': levels = {levels:g} must be a whole number >= 0 (0: not quantized)")
    if kind == "radial":
        edges, height = data["ring_edges_m"], data["height_m"]
        if edges.ndim != 1 or height.ndim != 1 or len(height) < 1 or len(edges) != len(height) + 1:
            raise EdofprojError(
                f"DOE file '{path}': {len(height) if height.ndim == 1 else height.shape} heights need "
                f"one more ring edge, got {len(edges) if edges.ndim == 1 else edges.shape} ring edges; {hint}"
            )
        if "level" in data and data["level"].shape != height.shape:
            raise EdofprojError(f"DOE file '{path}': {data['level'].shape[0]} levels for {len(height)} rings")
        if edges.dtype.kind not in "fiu" or not np.all(np.isfinite(edges)):
            raise EdofprojError(f"DOE file '{path}': ring_edges_m must be finite numbers")
        if edges[0] < 0 or not np.all(np.diff(edges) > 0):
            bad = int(np.argmax(np.diff(edges) <= 0)) if edges[0] >= 0 else 0
            raise EdofprojError(
                f"DOE file '{path}': ring edges must start at r >= 0 and increase strictly "
                f"(edge {bad}: {edges[bad]:.6g} m, edge {bad + 1}: {edges[min(bad + 1, len(edges) - 1)]:.6g} m)"
            )
    else:
        height = data["height_map_m"]
        if height.ndim != 2 or height.shape[0] != height.shape[1] or height.shape[0] < 1:
            raise EdofprojError(f"DOE file '{path}': height_map_m must be a square (N, N) map, got {height.shape}")
    if height.dtype.kind not in "fiu" or not np.all(np.isfinite(height)):
        raise EdofprojError(f"DOE file '{path}' contains NaN or infinite heights")
    if kind == "radial":
        _check_radial_levels(data, path, int(levels))


#: Largest distance of a quantized design's height from its level, in level steps.
LEVEL_GRID_TOLERANCE = 1e-3


def _check_radial_levels(data: dict[str, np.ndarray], path: Path, levels: int) -> None:
    """A radial design covers its aperture (outermost ring edge >= ``aperture_radius_m``); a
    quantized one (``levels > 0``) has every ``level`` in ``0..levels - 1`` and, with ``h2pi_m``,
    every height within :data:`LEVEL_GRID_TOLERANCE` steps of the grid ``L h_2pi / levels``, on the
    ring's ``level`` when the file gives one."""
    edges, height = data["ring_edges_m"], np.asarray(data["height_m"], dtype=np.float64)
    aperture = float(data["aperture_radius_m"])
    if edges[-1] < aperture * (1 - 1e-9):
        raise EdofprojError(
            f"DOE file '{path}': the aperture (radius {aperture * 1e3:.6g} mm) exceeds the outermost ring edge "
            f"({edges[-1] * 1e3:.6g} mm): the rings do not cover the aperture"
        )
    if levels == 0:
        return
    if "level" in data:
        level = data["level"]
        if level.dtype.kind not in "iu" or np.any(level < 0) or np.any(level >= levels):
            raise EdofprojError(f"DOE file '{path}': ring levels must be whole numbers in 0..{levels - 1}")
    if "h2pi_m" not in data:
        return
    h2pi = _scalar(data, "h2pi_m", path)
    if not (np.isfinite(h2pi) and h2pi > 0):
        raise EdofprojError(f"DOE file '{path}': h2pi_m = {h2pi:g} must be positive and finite")
    steps = height / (h2pi / levels)
    nearest = np.round(steps)
    off = np.abs(steps - nearest)
    if np.any(off > LEVEL_GRID_TOLERANCE) or np.any(height < -1e-12) or np.any(nearest > levels):
        ring = int(np.argmax((off > LEVEL_GRID_TOLERANCE) | (height < -1e-12) | (nearest > levels)))
        raise EdofprojError(
            f"DOE file '{path}': ring {ring}'s height {height[ring] * 1e9:.4g} nm is not one of the {levels} levels "
            f"of {h2pi / levels * 1e9:.4g} nm in [0, h2pi_m]: a quantized design's heights lie on its level grid"
        )
    if "level" in data and np.any(np.mod(nearest.astype(np.int64), levels) != data["level"]):
        ring = int(np.argmax(np.mod(nearest.astype(np.int64), levels) != data["level"]))
        raise EdofprojError(
            f"DOE file '{path}': ring {ring} has level {int(data['level'][ring])} but height "
            f"{height[ring] * 1e9:.4g} nm (level {int(nearest[ring]) % levels})"
        )


def load_doe(path: str | Path) -> DOE:
    """Load a design written by :func:`save_doe` (checked by :func:`validate_design`)."""
    path = Path(path)
    data = read_arrays(path, "DOE file")
    validate_design(data, path)
    kind = str(data["kind"])
    levels = int(data["levels"]) or None
    common = dict(
        aperture_radius_m=float(data["aperture_radius_m"]),
        design_wavelength_m=float(data["design_wavelength_m"]),
        levels=levels,
        material=str(data["material"]),
        description=str(data["description"]),
    )
    if kind == "radial":
        return TabulatedRadialDOE(data["ring_edges_m"], data["height_m"], **common)
    return TabulatedDOE2D(data["height_map_m"], float(data["pitch_m"]), **common)
