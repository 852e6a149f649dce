"""Refractive index of DOE materials.

Fused silica follows the Sellmeier equation of Malitson (1965), lambda in micrometres:

    n^2(lambda) - 1 = sum_i B_i lambda^2 / (lambda^2 - C_i^2)

with B = (0.6961663, 0.4079426, 0.8974794), C = (0.0684043, 0.1162414, 9.896161) um.
One 2pi wave of phase at the design wavelength ``lambda_d`` needs the height
``h_2pi = lambda_d / (n(lambda_d) - 1)``.
"""

from __future__ import annotations

import numpy as np

from ..errors import EdofprojError

_SELLMEIER = {
    "fused_silica": ((0.6961663, 0.4079426, 0.8974794), (0.0684043, 0.1162414, 9.896161)),
}

MATERIALS = tuple(_SELLMEIER)


def refractive_index(wavelength_m, material: str = "fused_silica"):
    """Refractive index ``n(lambda)`` of ``material`` (Sellmeier), for wavelengths in metres."""
    if material not in _SELLMEIER:
        raise EdofprojError(f"unknown material '{material}' (known: {', '.join(MATERIALS)})")
    b, c = _SELLMEIER[material]
    lam_um2 = (np.asarray(wavelength_m, dtype=float) * 1e6) ** 2
    n2 = 1.0 + sum(bi * lam_um2 / (lam_um2 - ci**2) for bi, ci in zip(b, c))
    return np.sqrt(n2)


def height_2pi_m(design_wavelength_m: float, material: str = "fused_silica") -> float:
    """Height of one 2pi wave at the design wavelength: ``lambda_d / (n(lambda_d) - 1)``."""
    return float(design_wavelength_m / (refractive_index(design_wavelength_m, material) - 1.0))
