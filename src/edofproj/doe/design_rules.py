"""Design for manufacture: radial DOEs that cannot have rings narrower than the critical dimension.

:class:`MinimumFeatureRadialDOE` evaluates an inner radial DOE only at the centres of blocks
of width ``w >= min_feature``: the radius axis ``[0, R]`` is cut into ``B = floor(R / w)``
blocks ``[b w, (b + 1) w)`` (the last one absorbs the remainder, ``[(B - 1) w, R]``), and

    h(r) = finish( h_inner( c_b(r) ) ),      c_b = centre of the block containing r,

with ``finish`` the usual wrap + straight-through quantization. Every constant-level zone is
a union of whole blocks, so every zone (and hence every mask feature: a union of zones) is at
least ``w`` wide; the gradient reaches the inner parameters through the block centres.

Block edges fall on the pupil rings when ``w`` is a whole number of ring widths: with
``grid_m`` given, ``w`` is rounded *up* to a multiple of it. :func:`apply_design_rules` uses
the simulation's ring width ``R / (pupil_samples / 2)``, so the simulated, the saved
(``save_doe(doe, path, samples=pupil_samples)``) and the fabricated profile are the same.
"""

from __future__ import annotations

import math

import torch

from ..errors import EdofprojError
from .base import RadialDOE, require_resolved_feature


def block_width_m(min_feature_m: float, aperture_radius_m: float, grid_m: float | None = None) -> float:
    """Block width: ``min_feature_m`` rounded up to a multiple of ``grid_m`` (if given)."""
    if not (min_feature_m > 0 and math.isfinite(min_feature_m)):
        raise EdofprojError(f"minimum feature {min_feature_m * 1e6:g} um must be > 0")
    width = min_feature_m
    if grid_m:
        width = math.ceil(min_feature_m / grid_m - 1e-9) * grid_m
    if width > aperture_radius_m:
        raise EdofprojError(
            f"minimum feature {min_feature_m * 1e6:g} um (block {width * 1e6:g} um) is wider than the aperture "
            f"radius {aperture_radius_m * 1e6:g} um"
        )
    return width


class MinimumFeatureRadialDOE(RadialDOE):
    """A radial DOE whose height is constant over blocks at least ``min_feature_m`` wide."""

    name = "min-feature"

    def __init__(self, inner: RadialDOE, min_feature_m: float, grid_m: float | None = None):
        if not getattr(inner, "radially_symmetric", False):
            raise EdofprojError(f"the minimum-feature rule needs a radial DOE; '{inner.name}' is 2-D")
        super().__init__(inner.aperture_radius_m, inner.design_wavelength_m, inner.levels, inner.material)
        self.quantize = inner.quantize
        self.inner = inner
        self.min_feature_m = float(min_feature_m)
        self.block_m = block_width_m(self.min_feature_m, self.aperture_radius_m, grid_m)
        self.blocks = max(int(math.floor(self.aperture_radius_m / self.block_m + 1e-9)), 1)

    def block_index(self, r_m: torch.Tensor) -> torch.Tensor:
        """Block of each radius (the last block runs to the aperture edge and beyond)."""
        return torch.clamp(torch.floor(r_m / self.block_m + 1e-9).long(), 0, self.blocks - 1)

    def block_centres_m(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Centre of each block; the last block is ``[(B - 1) w, R]``."""
        starts = torch.arange(self.blocks, dtype=dtype, device=device) * self.block_m
        ends = torch.cat([starts[1:], torch.tensor([self.aperture_radius_m], dtype=dtype, device=device)])
        return 0.5 * (starts + ends)

    def raw_height_m(self, r_m):
        """Unwrapped height (m) ``h_inner(c_b(r))``: the inner DOE evaluated at the centre of the block that
        contains each radius; shape of ``r_m``. Gradients reach the inner parameters through the centres."""
        centres = self.block_centres_m(r_m.dtype, r_m.device)
        return self.inner.raw_height_m(centres)[self.block_index(r_m)]

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if pupil samples ``ring_width_m`` apart are wider
        than a block, naming the ``pupil_samples`` needed."""
        require_resolved_feature(self.block_m, ring_width_m, self.aperture_radius_m, "the minimum-feature blocks are")

    def describe(self):
        """The inner DOE's description followed by the block width and the minimum feature (um)."""
        return (
            f"{self.inner.describe()}, constant over {self.block_m * 1e6:.2f} um blocks "
            f"(minimum feature {self.min_feature_m * 1e6:g} um)"
        )


def apply_design_rules(doe, cfg):
    """The DOE the trainer optimizes: ``doe`` wrapped in :class:`MinimumFeatureRadialDOE` when
    ``cfg.doe.min_feature_um > 0`` (blocks aligned to the ``cfg.psf.pupil_samples`` rings), else ``doe``.

    Save the result with ``save_doe(doe, path, samples=cfg.psf.pupil_samples)`` (or a multiple) so
    the file's rings fall on the block edges. Wrap before loading a checkpoint: the inner DOE's
    parameters live under ``inner.``."""
    min_feature_um = float(getattr(cfg.doe, "min_feature_um", 0.0) or 0.0)
    if min_feature_um <= 0:
        return doe
    if not getattr(doe, "radially_symmetric", False):
        raise EdofprojError(
            f"doe.min_feature_um={min_feature_um:g} applies to radial DOEs only; the '{doe.name}' DOE is 2-D"
        )
    if isinstance(doe, MinimumFeatureRadialDOE):
        return doe
    rings = max(int(cfg.psf.pupil_samples) // 2, 1)
    return MinimumFeatureRadialDOE(doe, min_feature_um * 1e-6, grid_m=doe.aperture_radius_m / rings)
