"""The paper's DOE: a radial height profile given by an MLP over a positional encoding.

    h(r) = h_2pi * sigmoid(F_theta(p(r / R)))                         (paper Eq. 10)
    p(u) = (u, sin(2^0 pi u), cos(2^0 pi u), ..., sin(2^{L-1} pi u), cos(2^{L-1} pi u))   (Eq. 11)

The output is mapped into one wave [0, h_2pi) at the design wavelength. The last layer is
zero-initialized, so an untrained MLP gives a constant height: the bare lens.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..errors import SamplingError
from .base import RadialDOE, require_resolved_feature


def positional_encoding(u: torch.Tensor, frequencies: int) -> torch.Tensor:
    """``p(u)`` of Eq. 11 along a new last axis: ``1 + 2 L`` features."""
    feats = [u]
    for k in range(frequencies):
        arg = (2.0**k) * math.pi * u
        feats += [torch.sin(arg), torch.cos(arg)]
    return torch.stack(feats, dim=-1)


class RadialMLPDOE(RadialDOE):
    """Radially symmetric DOE whose height is an MLP of the encoded, normalized radius."""

    name = "mlp"

    def __init__(
        self,
        aperture_radius_m,
        design_wavelength_m=550e-9,
        levels=16,
        material="fused_silica",
        frequencies: int = 9,
        hidden: int = 64,
        layers: int = 3,
        clear_core_fraction: float = 0.0,
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.clear_core_radius_m = float(clear_core_fraction) * self.aperture_radius_m
        self.frequencies = int(frequencies)
        blocks: list[nn.Module] = []
        width = 1 + 2 * self.frequencies
        for _ in range(layers):
            blocks += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        last = nn.Linear(width, 1)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        blocks.append(last)
        self.mlp = nn.Sequential(*blocks)

    def raw_height_m(self, r_m):
        """Unwrapped height (m) ``h(r) = h_2pi sigmoid(F_theta(p(r / R)))`` (Eq. 10), in ``(0, h_2pi)``,
        0 inside a clear core (:meth:`~edofproj.doe.base.RadialDOE.clear_core`); shape and dtype of ``r_m``
        (the MLP runs in its parameters' dtype)."""
        param_dtype = self.mlp[0].weight.dtype
        u = (r_m / self.aperture_radius_m).to(param_dtype)
        out = self.mlp(positional_encoding(u, self.frequencies)).squeeze(-1)
        return self.clear_core(r_m, (self.h2pi_m * torch.sigmoid(out)).to(r_m.dtype))

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if samples ``ring_width_m`` apart give fewer than 4
        per period of the highest encoding frequency, ``2^(2-L) R``; the message names the ``pupil_samples``
        needed. ``L = 0`` accepts any sampling."""
        if self.frequencies == 0:
            return
        # Highest encoding frequency 2^{L-1} pi / R  ->  period 2^{2-L} R; want >= 4 samples per period.
        period_m = self.aperture_radius_m * 2.0 ** (2 - self.frequencies)
        if ring_width_m > period_m / 4:
            need = int(math.ceil(8 * self.aperture_radius_m / period_m)) * 2
            raise SamplingError(
                f"the MLP's positional encoding (L = {self.frequencies}) has a period of "
                f"{period_m * 1e6:.1f} um but pupil samples are {ring_width_m * 1e6:.2f} um apart: "
                f"use pupil_samples >= {need} or lower doe.mlp_frequencies"
            )

    def describe(self):
        """``radial MLP, L = <frequencies>;`` followed by :meth:`DOE.describe`."""
        return f"radial MLP, L = {self.frequencies}; " + super().describe()


class FreeRadialDOE(RadialDOE):
    """One free height parameter per ring (piecewise-constant radial profile)."""

    name = "free"

    def __init__(
        self,
        aperture_radius_m,
        design_wavelength_m=550e-9,
        levels=16,
        material="fused_silica",
        rings: int = 512,
        clear_core_fraction: float = 0.0,
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.clear_core_radius_m = float(clear_core_fraction) * self.aperture_radius_m
        self.rings = int(rings)
        self.heights = nn.Parameter(torch.zeros(self.rings, dtype=torch.float64))

    def raw_height_m(self, r_m):
        """Unwrapped height (m) ``h(r) = h_2pi * theta[floor(N r / R)]`` for ``N`` rings (radii beyond the
        aperture take the outer ring's value), 0 inside a clear core; shape and dtype of ``r_m``."""
        idx = torch.clamp((r_m / self.aperture_radius_m * self.rings).long(), 0, self.rings - 1)
        return self.clear_core(r_m, (self.heights * self.h2pi_m)[idx].to(r_m.dtype))

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if pupil samples ``ring_width_m`` apart are wider
        than a ring, ``R / N``, naming the ``pupil_samples`` needed."""
        require_resolved_feature(
            self.aperture_radius_m / self.rings,
            ring_width_m,
            self.aperture_radius_m,
            f"the free profile's {self.rings} rings are",
        )
