"""Fixed DOE designs: bare lens, cubic phase plate, axicon, multifocal zones.

All are expressed as an unwrapped optical path difference (OPD) at the design wavelength
``lambda_d``; the height is ``h = OPD / (n(lambda_d) - 1)`` before wrapping to one wave.

* lens:       h = 0 (no DOE; the projector lens alone).
* cubic:      phase = 2 pi alpha ((x/R)^3 + (y/R)^3), alpha in waves (Dowski & Cathey 1995).
* axicon:     a focal line from z_near to z_far: OPD = -(P/2) r^2 + a r, so that a ray at
              radius r crosses the axis at 1/z(r) = 1/v + P - a/r (paraxial). The rim (r = R)
              focuses at z_near and r = R/4 at z_far (the inner 1/16 of the pupil area
              focuses beyond): a = (R/3)(1/z_near - 1/z_far), P = 1/z_near + a/R - 1/v.
* multifocal: N equal-area annular zones; zone i adds the lens power that moves the focus
              from v to z_i: OPD = -(r^2 / 2) (1/z_i - 1/v).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import SamplingError
from .base import DOE, RadialDOE

# A pupil sample may advance the unwrapped phase by at most this much (radians);
# beyond it the piecewise-constant pupil no longer represents the design.
MAX_PHASE_STEP_RAD = math.pi / 2


def _check_phase_step(step_rad: float, what: str, ring_width_m: float) -> None:
    if step_rad > MAX_PHASE_STEP_RAD:
        factor = step_rad / MAX_PHASE_STEP_RAD
        raise SamplingError(
            f"the {what} changes phase by {step_rad:.2f} rad between pupil samples "
            f"({ring_width_m * 1e6:.2f} um apart; max {MAX_PHASE_STEP_RAD:.2f}): increase "
            f"pupil_samples at least {factor:.1f}x"
        )


class LensOnly(RadialDOE):
    """No DOE: zero height everywhere."""

    name = "lens"

    def __init__(self, aperture_radius_m: float, design_wavelength_m: float = 550e-9, **_):
        super().__init__(aperture_radius_m, design_wavelength_m, levels=None)

    def raw_height_m(self, r_m):
        """Zero height at every radius (shape of ``r_m``)."""
        return torch.zeros_like(r_m)


class CubicPhasePlate(DOE):
    """2-D cubic phase plate, ``alpha_waves`` waves of phase at the aperture corner axis."""

    name = "cubic"

    def __init__(
        self,
        aperture_radius_m,
        design_wavelength_m=550e-9,
        levels=16,
        material="fused_silica",
        alpha_waves: float = 20.0,
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.alpha_waves = float(alpha_waves)

    def raw_height_map_m(self, x_m, y_m):
        """Unwrapped height (m) ``h = alpha ((x/R)^3 + (y/R)^3) h_2pi`` with ``h_2pi = lambda_d / (n(lambda_d) - 1)``,
        i.e. ``2 pi alpha ((x/R)^3 + (y/R)^3)`` radians at ``lambda_d``; broadcast shape of ``x_m``, ``y_m``."""
        R = self.aperture_radius_m
        waves = self.alpha_waves * ((x_m / R) ** 3 + (y_m / R) ** 3)
        return waves * self.h2pi_m

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if the steepest phase step between samples
        ``ring_width_m`` apart, ``2 pi * 3 |alpha| * ring_width_m / R`` (the gradient at the aperture edge),
        exceeds ``MAX_PHASE_STEP_RAD`` (pi/2)."""
        step = 2 * math.pi * 3 * abs(self.alpha_waves) * ring_width_m / self.aperture_radius_m
        _check_phase_step(step, "cubic phase", ring_width_m)

    def describe(self):
        """``cubic phase plate, alpha = ... waves;`` followed by :meth:`DOE.describe`."""
        return f"cubic phase plate, alpha = {self.alpha_waves:g} waves; " + super().describe()


class Axicon(RadialDOE):
    """Lens + axicon: a conical phase that spreads the focus along a line from z_near to z_far."""

    name = "axicon"

    def __init__(
        self,
        aperture_radius_m,
        design_wavelength_m=550e-9,
        levels=16,
        material="fused_silica",
        focus_distance_m: float = 0.5,
        near_m: float = 0.3,
        far_m: float = 0.8,
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        R = aperture_radius_m
        self.near_m, self.far_m = float(near_m), float(far_m)
        self.slope = (R / 3.0) * (1.0 / near_m - 1.0 / far_m)  # a (dimensionless OPD slope)
        self.power = 1.0 / near_m + self.slope / R - 1.0 / focus_distance_m  # P (1/m)
        self.n_d_minus_1 = float(self.refractive_index(design_wavelength_m)) - 1.0

    def raw_height_m(self, r_m):
        """Unwrapped height (m) ``h(r) = (-(P/2) r^2 + a r) / (n(lambda_d) - 1)``: the OPD of a lens of power
        ``P`` (1/m) plus a cone of slope ``a`` (see the module docstring); shape of ``r_m``."""
        return (-0.5 * self.power * r_m**2 + self.slope * r_m) / self.n_d_minus_1

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if the phase step between samples ``ring_width_m``
        apart, ``2 pi (|a| + |P| R) ring_width_m / lambda_d`` (the steepest OPD gradient), exceeds
        ``MAX_PHASE_STEP_RAD`` (pi/2)."""
        gradient = abs(self.slope) + abs(self.power) * self.aperture_radius_m  # max |d OPD / dr|
        step = 2 * math.pi * gradient * ring_width_m / self.design_wavelength_m
        _check_phase_step(step, "axicon", ring_width_m)

    def describe(self):
        """``axicon, focal line <near>-<far> mm;`` followed by :meth:`DOE.describe`."""
        return f"axicon, focal line {self.near_m * 1e3:.0f}-{self.far_m * 1e3:.0f} mm; " + super().describe()


class Multifocal(RadialDOE):
    """Equal-area annular zones, each refocusing the lens to its own distance."""

    name = "multifocal"

    def __init__(
        self,
        aperture_radius_m,
        design_wavelength_m=550e-9,
        levels=16,
        material="fused_silica",
        focus_distance_m: float = 0.5,
        foci_m=(0.35, 0.5, 0.7),
    ):
        super().__init__(aperture_radius_m, design_wavelength_m, levels, material)
        self.foci_m = [float(f) for f in foci_m]
        n = len(self.foci_m)
        self.zone_edges_m = aperture_radius_m * np.sqrt(np.arange(n + 1) / n)
        n_d = float(self.refractive_index(design_wavelength_m))
        self.curvatures = [-(1.0 / f - 1.0 / focus_distance_m) / (2.0 * (n_d - 1.0)) for f in self.foci_m]

    def raw_height_m(self, r_m):
        """Unwrapped height (m) ``h(r) = c_i r^2`` in zone ``i`` (the equal-area zone containing ``r``), with
        ``c_i = -(1/z_i - 1/v) / (2 (n(lambda_d) - 1))`` the curvature that refocuses from ``v`` to ``z_i``;
        shape of ``r_m``. Radii beyond ``R`` belong to the outer zone."""
        edges = torch.as_tensor(self.zone_edges_m[1:-1], dtype=r_m.dtype, device=r_m.device)
        zone = torch.bucketize(r_m, edges)
        curv = torch.as_tensor(self.curvatures, dtype=r_m.dtype, device=r_m.device)[zone]
        return curv * r_m**2

    def check_sampling(self, ring_width_m):
        """Raise :class:`~edofproj.errors.SamplingError` if the phase step between samples ``ring_width_m``
        apart at the aperture edge of the strongest zone, ``2 pi * 2 max|c_i| (n_d - 1) R ring_width_m / lambda_d``,
        exceeds ``MAX_PHASE_STEP_RAD`` (pi/2). (The height jumps between zones are not sampling limits.)"""
        n_d = float(self.refractive_index(self.design_wavelength_m))
        worst = max(abs(c) for c in self.curvatures) * 2 * (n_d - 1.0)
        step = 2 * math.pi * worst * self.aperture_radius_m * ring_width_m / self.design_wavelength_m
        _check_phase_step(step, "multifocal zone power", ring_width_m)

    def describe(self):
        """``multifocal, zones focused at ... mm;`` followed by :meth:`DOE.describe`."""
        foci = ", ".join(f"{f * 1e3:.0f}" for f in self.foci_m)
        return f"multifocal, zones focused at {foci} mm; " + super().describe()
