"""The DOE interface used by the propagation engines.

A DOE is a ``torch.nn.Module`` that gives its fabricated (wrapped, optionally quantized)
height in metres:

* radially symmetric designs implement :meth:`RadialDOE.raw_height_m` of the radius and
  are simulated by the fast radial engine or the 2-D engine;
* general designs implement :meth:`DOE.raw_height_map_m` of (x, y) and need the 2-D engine.

The phase added at wavelength lambda is ``2 pi (n(lambda) - 1) h / lambda``.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from ..errors import SamplingError
from ..optics.materials import height_2pi_m, refractive_index
from .quantization import wrap_and_quantize


def require_resolved_feature(feature_m: float, sample_m: float, aperture_radius_m: float, what: str) -> None:
    """Refuse pupil samples wider than the design's narrowest feature (its rings or zones):
    the sampling would merge features it cannot resolve. Names the ``pupil_samples`` needed."""
    if sample_m > feature_m * (1 + 1e-6):
        need = 2 * math.ceil(aperture_radius_m / feature_m - 1e-9)
        raise SamplingError(
            f"{what} {feature_m * 1e6:.2f} um wide but pupil samples are {sample_m * 1e6:.2f} um apart: "
            f"use pupil_samples >= {need}"
        )


class DOE(nn.Module):
    """Base class: a thin phase element of a given material, wrapped at the design wavelength."""

    radially_symmetric = False
    name = "doe"

    def __init__(
        self,
        aperture_radius_m: float,
        design_wavelength_m: float = 550e-9,
        levels: int | None = 16,
        material: str = "fused_silica",
    ):
        super().__init__()
        self.aperture_radius_m = float(aperture_radius_m)
        self.design_wavelength_m = float(design_wavelength_m)
        self.levels = int(levels) if levels else None
        self.material = material
        self.h2pi_m = height_2pi_m(self.design_wavelength_m, material)
        self.quantize = self.levels is not None

    # -- what subclasses implement -------------------------------------------------
    def raw_height_map_m(self, x_m: torch.Tensor, y_m: torch.Tensor) -> torch.Tensor:
        """Unwrapped height (m) at pupil coordinates; override in 2-D designs."""
        raise NotImplementedError

    @property
    def device(self) -> torch.device:
        """The device of the design's parameters and buffers (the CPU for a design with none): where
        the coordinates it is evaluated at must be."""
        for tensor in itertools.chain(self.parameters(), self.buffers()):
            return tensor.device
        return torch.device("cpu")

    # -- what engines call -----------------------------------------------------------
    def finish(self, raw_height_m: torch.Tensor) -> torch.Tensor:
        """Wrap to one wave and quantize (straight-through) when ``self.quantize``."""
        return wrap_and_quantize(raw_height_m, self.h2pi_m, self.levels if self.quantize else None)

    def height_map_m(self, x_m: torch.Tensor, y_m: torch.Tensor) -> torch.Tensor:
        """Fabricated height (m) at pupil coordinates (x, y)."""
        return self.finish(self.raw_height_map_m(x_m, y_m))

    def refractive_index(self, wavelength_m):
        """Refractive index ``n(lambda)`` of the DOE's material (Sellmeier) at ``wavelength_m``
        (metres; a float or an array, returned as a NumPy value of the same shape)."""
        return refractive_index(wavelength_m, self.material)

    def check_sampling(self, ring_width_m: float) -> None:
        """Raise :class:`~edofproj.errors.SamplingError` if pupil samples of this width
        cannot resolve the design. The default accepts any sampling."""

    def describe(self) -> str:
        """One line for logs and reports: the design's name, its height levels (or "continuous") and
        the design wavelength in nm. Subclasses prepend their own parameters."""
        levels = f"{self.levels} levels" if self.quantize else "continuous"
        return f"{self.name} ({levels}, lambda_d = {self.design_wavelength_m * 1e9:.0f} nm)"


class RadialDOE(DOE):
    """A rotationally symmetric DOE: height depends on the radius only."""

    radially_symmetric = True
    #: Radius (m) inside which a learned design is left clear (zero height: the bare lens there).
    clear_core_radius_m = 0.0

    def raw_height_m(self, r_m: torch.Tensor) -> torch.Tensor:
        """Unwrapped height (m) at radius ``r_m``; override in subclasses."""
        raise NotImplementedError

    def clear_core(self, r_m: torch.Tensor, height_m: torch.Tensor) -> torch.Tensor:
        """``height_m`` with 0 at radii ``r < clear_core_radius_m``: the pupil's centre passes the lens's
        wavefront unchanged (its in-focus PSF keeps the bare lens's sharp core), the DOE acts on the
        annulus outside. Unchanged when the core is 0."""
        if self.clear_core_radius_m <= 0:
            return height_m
        return torch.where(r_m < self.clear_core_radius_m, torch.zeros_like(height_m), height_m)

    def describe(self) -> str:
        """:meth:`DOE.describe`, after ``clear core <f> R;`` when the design has one."""
        core = (
            f"clear core {self.clear_core_radius_m / self.aperture_radius_m:.2f} R; "
            if self.clear_core_radius_m
            else ""
        )
        return core + super().describe()

    def height_m(self, r_m: torch.Tensor) -> torch.Tensor:
        """Fabricated height (m) at radius ``r_m``."""
        return self.finish(self.raw_height_m(r_m))

    def raw_height_map_m(self, x_m: torch.Tensor, y_m: torch.Tensor) -> torch.Tensor:
        """Unwrapped height (m) at pupil coordinates: ``raw_height_m(sqrt(x^2 + y^2))``, so that the
        2-D engine can simulate a radial design; the result has the broadcast shape of ``x_m``, ``y_m``."""
        return self.raw_height_m(torch.sqrt(x_m**2 + y_m**2))
