"""Photometric compensation: per-pixel division by the reflectance (the sharp-projector baseline).

On a surface ``c = s ⊙ A(L) + a`` (:mod:`edofproj.imaging.surfaces`), a projector that were
perfectly sharp (``A`` the identity) would show the goal ``g`` for

    L = clip( (g - a) / s~, 0, 1 ),     s~ = max(s, MIN_REFLECTANCE),

the classic radiometric compensation (Nayar et al. 2003; the linear core of CompenNet and its
successors). It removes the surface's colour and texture but not the blur: the division is
itself blurred by the PSF before the surface multiplies, so at texture edges it over- and
undershoots by the blur width. ``MIN_REFLECTANCE`` keeps black spots from dividing by zero (they
cannot be lit anyway; the clip then sends the full output).
"""

from __future__ import annotations

import torch

#: Reflectances below this are treated as this in the division (a black spot is lit fully, not infinitely).
MIN_REFLECTANCE = 0.02


def light_for_goal(goal: torch.Tensor, reflectance: torch.Tensor, ambient: torch.Tensor) -> torch.Tensor:
    """The light the surface must receive to show ``goal``: ``(g - a) / max(s, MIN_REFLECTANCE)``, unclipped
    (``(B, 3, H, W)``; ``reflectance (B|1, 3, H, W)``, ``ambient (B|1, 3, H|1, W|1)``)."""
    rho = reflectance.to(goal).clamp_min(MIN_REFLECTANCE)
    return (goal - ambient.to(goal)) / rho


def photometric_compensation(goal: torch.Tensor, reflectance: torch.Tensor, ambient: torch.Tensor) -> torch.Tensor:
    """The photometric-only baseline ``clip((g - a) / s~, 0, 1)`` (module docstring), no deblurring."""
    return light_for_goal(goal, reflectance, ambient).clamp(0.0, 1.0)
