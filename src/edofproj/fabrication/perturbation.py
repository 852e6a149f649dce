"""Fabrication errors of a mask set, and the as-fabricated DOE they produce.

Error model (one draw per Monte Carlo trial):

* etch depth: mask ``j`` etches ``d_j (1 + e_j)`` instead of ``d_j = 2^j s``, ``e_j ~ N(0, sigma_e)``;
* overlay: mask ``j >= 1`` is shifted laterally by ``(dx_j, dy_j) ~ N(0, sigma_m^2 I)`` against
  mask 0 (which carries the alignment marks);
* decentre: the whole DOE is shifted by ``(cx, cy) ~ N(0, sigma_d^2 I)`` against the lens axis.

The as-fabricated height (the wafer surface, top level ``(N - 1) s``, is not etched) is

    h(x, y) = (N - 1) s - sum_j d_j (1 + e_j) [ (x - cx - dx_j, y - cy - dy_j) lies in an etched annulus of mask j ].

Heights are physical: no wrapping, no re-quantization (an etch error must stay an error at
every wavelength).

:class:`FabricatedDOE2D` is this formula (2-D engine). :class:`FabricatedRadialDOE` is the
radially symmetric proxy for the radial engine: it takes the cross-section of the shifted
masks along the shift direction, ``a -> a + dx_j`` for every mask edge ``a > 0``, revolved
about the axis. A real shift moves an edge by ``dx_j cos(theta)``; the proxy applies the full
``dx_j`` at every azimuth, so it overstates the effect of overlay errors. It cannot model
decentre (use the 2-D engine).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..doe.base import DOE, RadialDOE, require_resolved_feature
from ..errors import EdofprojError
from .masks import MaskLayer, top_surface_m
from .profile import RadialProfile


@dataclass(frozen=True)
class FabricationErrors:
    """One draw of the error model: ``etch_scale`` (k,) = 1 + e_j, ``mask_shift_m`` (k, 2), ``decentre_m`` (2,)."""

    etch_scale: np.ndarray
    mask_shift_m: np.ndarray
    decentre_m: np.ndarray

    @classmethod
    def none(cls, masks: int) -> "FabricationErrors":
        """The error-free draw for ``masks`` masks: every etch scale 1, no overlay shift, no decentre
        (the as-fabricated DOE is then the nominal mask set)."""
        return cls(np.ones(masks), np.zeros((masks, 2)), np.zeros(2))

    @classmethod
    def sample(
        cls, rng: np.random.Generator, masks: int, etch_error_pct: float, misalignment_m: float, decentre_m: float
    ) -> "FabricationErrors":
        """Draw etch scales, overlay shifts (mask 0 is the reference: no shift) and a decentre."""
        etch = 1.0 + rng.normal(0.0, etch_error_pct / 100.0, masks)
        shift = rng.normal(0.0, misalignment_m, (masks, 2)) if misalignment_m > 0 else np.zeros((masks, 2))
        shift[0] = 0.0
        centre = rng.normal(0.0, decentre_m, 2) if decentre_m > 0 else np.zeros(2)
        return cls(etch, shift, centre)

    def as_dict(self) -> dict:
        """JSON-ready mapping: ``etch_scale`` (k values ``1 + e_j``), ``mask_shift_um`` (k pairs ``(dx_j, dy_j)``)
        and ``decentre_um`` (``(cx, cy)``), shifts in micrometres."""
        return {
            "etch_scale": self.etch_scale.tolist(),
            "mask_shift_um": (self.mask_shift_m * 1e6).tolist(),
            "decentre_um": (self.decentre_m * 1e6).tolist(),
        }


def _flat_edges(mask: MaskLayer) -> np.ndarray:
    """Etched annuli as one sorted edge list: r is etched iff an odd number of edges are <= r."""
    return np.asarray(mask.annuli_m, dtype=float).reshape(-1)


def _etched(flat_edges: torch.Tensor, r_m: torch.Tensor) -> torch.Tensor:
    if flat_edges.numel() == 0:
        return torch.zeros_like(r_m, dtype=torch.bool)
    return torch.remainder(torch.searchsorted(flat_edges, r_m.contiguous(), right=True), 2) == 1


class _Fabricated:
    """Shared data of the as-fabricated DOEs: per-mask edges and depths, the top surface."""

    def _setup(self, profile: RadialProfile, masks: list[MaskLayer], errors: FabricationErrors) -> None:
        if len(errors.etch_scale) != len(masks):
            raise EdofprojError(f"{len(errors.etch_scale)} etch errors for {len(masks)} masks")
        self.top_m = top_surface_m(profile)
        self.depths_m = [m.etch_depth_m * float(s) for m, s in zip(masks, errors.etch_scale)]
        self.errors = errors
        self.nominal_zone_m = profile.narrowest_zone_m()

    def finish(self, raw_height_m):
        """Physical heights: no wrapping and no quantization."""
        return raw_height_m


class FabricatedRadialDOE(_Fabricated, RadialDOE):
    """Radial proxy of the as-fabricated DOE (see the module docstring).

    Piecewise constant with steps at :meth:`edges_m`: simulate it on
    :func:`.ring_engine.radial_engine_on_edges` (exact); a plain radial engine samples it at its
    ring centres and misses sub-ring edge shifts."""

    name = "fabricated"

    def __init__(self, profile: RadialProfile, masks: list[MaskLayer], errors: FabricationErrors):
        RadialDOE.__init__(self, profile.aperture_radius_m, profile.design_wavelength_m, None, profile.material)
        self._setup(profile, masks, errors)
        if np.any(errors.decentre_m != 0):
            raise EdofprojError("a decentred DOE is not radially symmetric: model decentre with the 2-D engine")
        self.flat_edges = []
        for mask, (dx, _) in zip(masks, errors.mask_shift_m):
            edges = _flat_edges(mask)
            shifted = np.where(edges > 0, np.clip(edges + dx, 0.0, None), 0.0)
            self.flat_edges.append(np.maximum.accumulate(shifted) if len(shifted) else shifted)

    def edges_m(self) -> np.ndarray:
        """Every radius in (0, R) where the as-fabricated height may step."""
        edges = np.concatenate(self.flat_edges + [np.empty(0)])
        return np.unique(edges[(edges > 0) & (edges < self.aperture_radius_m)])

    def raw_height_m(self, r_m):
        """As-fabricated height (m) ``h(r) = (N - 1) s - sum_j d_j (1 + e_j) [r in an etched annulus of the
        shifted mask j]`` (physical: not wrapped, not quantized); computed in float64, returned in the shape
        and dtype of ``r_m``."""
        height = torch.full_like(r_m, self.top_m, dtype=torch.float64)
        r = r_m.to(torch.float64)
        for edges, depth in zip(self.flat_edges, self.depths_m):
            height = height - depth * _etched(torch.as_tensor(edges, dtype=torch.float64, device=r.device), r).double()
        return height.to(r_m.dtype)

    def describe(self):
        """The fixed line ``as-fabricated DOE (radial proxy)``."""
        return "as-fabricated DOE (radial proxy)"


class FabricatedDOE2D(_Fabricated, DOE):
    """The as-fabricated DOE in 2-D: shifted masks and a decentred element (see the module docstring)."""

    name = "fabricated-2d"

    def __init__(self, profile: RadialProfile, masks: list[MaskLayer], errors: FabricationErrors):
        DOE.__init__(self, profile.aperture_radius_m, profile.design_wavelength_m, None, profile.material)
        self._setup(profile, masks, errors)
        self.flat_edges = [_flat_edges(m) for m in masks]

    def raw_height_map_m(self, x_m, y_m):
        """As-fabricated height (m) at pupil coordinates, the module's formula
        ``h = (N - 1) s - sum_j d_j (1 + e_j) [(x - cx - dx_j, y - cy - dy_j) etched by mask j]`` (physical: not
        wrapped, not quantized); computed in float64, returned in the broadcast shape and dtype of ``x_m``."""
        x = x_m.to(torch.float64) - float(self.errors.decentre_m[0])
        y = y_m.to(torch.float64) - float(self.errors.decentre_m[1])
        height = torch.full_like(x, self.top_m)
        for edges, depth, (dx, dy) in zip(self.flat_edges, self.depths_m, self.errors.mask_shift_m):
            r = torch.sqrt((x - dx) ** 2 + (y - dy) ** 2)
            height = height - depth * _etched(torch.as_tensor(edges, dtype=torch.float64, device=x.device), r).double()
        return height.to(x_m.dtype)

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if pupil samples ``ring_width_m`` apart are wider than
        the nominal profile's narrowest zone, naming the ``pupil_samples`` needed."""
        require_resolved_feature(
            self.nominal_zone_m, ring_width_m, self.aperture_radius_m, "the design's narrowest zone is"
        )

    def describe(self):
        """The fixed line ``as-fabricated DOE (2-D)``."""
        return "as-fabricated DOE (2-D)"
