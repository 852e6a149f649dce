"""What a textured surface can show: the target scaled into the achievable range.

On a surface of reflectance ``s`` under ambient ``a`` (:mod:`edofproj.imaging.surfaces`) a
perfectly sharp projector can show, per pixel and colour, anything in ``[a, a + s]`` and nothing
else: no compensation makes a dark spot brighter than ``a + s`` or a lit one darker than ``a``.
A target ``t`` in ``[0, 1]`` is therefore mapped to the *goal* appearance

    g = f + k t,

one affine map per image, the same gain ``k`` for the three colours (so the target's colours are
not tinted):

    f_c = Q_{1-q}( a_c )                       the floor: the ambient at most pixels, per colour;
    k   = clip( Q_q( min_c (a_c + s_c - f_c) ), 0, 1 )
                                              the gain: the headroom above the floor at most pixels,

``Q_p`` the ``p``-quantile over the image's pixels and ``q`` = :data:`OUTLIER_FRACTION` (2 %):
a few pixels darker or brighter than the rest (a crack, a specular spot, noise) do not lower the
contrast of the whole image; at most about ``2 q`` of the pixels cannot be reached (``g`` outside
``[a, a + s]`` there), whatever the target. A white screen without ambient (``s = 1, a = 0``)
gives ``f = 0, k = 1``: the goal is the target itself, as everywhere else in edofproj. Every
method on a textured surface is scored against ``g`` (it is what the best possible projection
shows), and the networks that know the surface are trained toward it.

The gain depends on the surface alone (:func:`surface_gain`). A surface whose gain is below
:data:`MIN_GAIN` cannot show an image (its goal spans fewer than 4 of an 8-bit projector's 256
grey levels: a black object, a surface lit only by the room), and :func:`require_visible`
refuses it in one line. Scores against a nearly constant goal measure the metrics' own
stabilizing constants, not the projection (SSIM's ``C2 = (0.03)^2`` exceeds the goal's variance
``k^2 var(t)`` for ``k < 0.03 / std(t) ~ 0.1``: an uncompensated projection of
``builtin:cpu-doe-unet``'s DOE scores SSIM 1 on a black surface, 0.98 at ``k = 0.003``, 0.84 at
``k = 0.01``, 0.36 at ``k = 0.05`` and 0.31 at ``k = 0.1``). Below :data:`DARK_GAIN`, or when more
than :data:`WARN_CLIPPED_FRACTION` of a target's pixels cannot be reached,
:func:`warn_if_out_of_reach` warns (:class:`SurfaceRangeWarning`) with the fraction clipped and
the contrast.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import torch

from ..errors import EdofprojError

#: Fraction of pixels (``q``) that may fall outside the achievable range, at each end.
OUTLIER_FRACTION = 0.02
#: A gain ``k`` below this: the surface cannot show an image (refused by :func:`require_visible`):
#: fewer than 4 of an 8-bit projector's grey levels.
MIN_GAIN = 4 / 255
#: A gain ``k`` below this: the surface is too dark for any target (warned; its scores are inflated).
DARK_GAIN = 0.05
#: More than this fraction of pixels out of reach for a given target: warned.
WARN_CLIPPED_FRACTION = 0.05
#: Slack when testing ``a <= g <= a + s`` (rounding).
RANGE_TOLERANCE = 1e-4


class SurfaceRangeWarning(UserWarning):
    """The surface cannot show the target: too dark, or too many pixels out of its range."""


class Goal(NamedTuple):
    """The goal appearance ``g = f + k t`` ``(B, 3, H, W)``, its floor ``f (B, 3, 1, 1)`` and gain ``k (B, 1, 1, 1)``."""

    image: torch.Tensor
    floor: torch.Tensor
    gain: torch.Tensor


def _quantile(values: torch.Tensor, q: float) -> torch.Tensor:
    """``q``-quantile over the last two axes, keeping them as 1."""
    flat = values.flatten(-2).float()
    return torch.quantile(flat, q, dim=-1, keepdim=True).unsqueeze(-1).to(values.dtype)


def achievable_goal(
    target: torch.Tensor, reflectance: torch.Tensor, ambient: torch.Tensor, outlier_fraction: float = OUTLIER_FRACTION
) -> Goal:
    """The goal ``g = f + k t`` (module docstring) for ``target (B, 3, H, W)`` in ``[0, 1]`` on a surface
    ``reflectance (B|1, 3, H, W)``, ``ambient (B|1, 3, H|1, W|1)``. Not differentiable (a target)."""
    with torch.no_grad():
        floor, gain = surface_gain(reflectance.to(target), ambient.to(target), outlier_fraction)
        floor, gain = floor.expand(target.shape[0], -1, -1, -1), gain.expand(target.shape[0], -1, -1, -1)
        return Goal(floor + gain * target.clamp(0.0, 1.0), floor, gain)


def surface_gain(
    reflectance: torch.Tensor, ambient: torch.Tensor, outlier_fraction: float = OUTLIER_FRACTION
) -> tuple[torch.Tensor, torch.Tensor]:
    """The floor ``f (B|1, 3, 1, 1)`` and gain ``k (B|1, 1, 1, 1)`` of the goal on a surface
    ``reflectance (B|1, 3, H, W)``, ``ambient (B|1, 3, H|1, W|1)`` (module docstring): what it
    can show, whatever the target."""
    if not 0.0 <= outlier_fraction < 0.5:
        raise EdofprojError(f"the outlier fraction {outlier_fraction:g} must lie in [0, 0.5)")
    with torch.no_grad():
        rho, amb = torch.broadcast_tensors(reflectance, ambient.to(reflectance))
        floor = _quantile(amb, 1.0 - outlier_fraction)  # (B, 3, 1, 1)
        headroom = (amb + rho - floor).amin(dim=1, keepdim=True)  # (B, 1, H, W)
        return floor, _quantile(headroom, outlier_fraction).clamp(0.0, 1.0)  # (B, 1, 1, 1)


def require_visible(
    reflectance: torch.Tensor, ambient: torch.Tensor, what: str = "the surface", hint: str = ""
) -> float:
    """The gain ``k`` of the surface (:func:`surface_gain`), or one line refusing a surface that
    cannot show an image (``k <`` :data:`MIN_GAIN`, module docstring); ``hint`` ends that line."""
    gain = float(surface_gain(reflectance, ambient)[1].min())
    if not gain >= MIN_GAIN:
        raise EdofprojError(
            f"{what} cannot show an image: the range it can show, [a, a + s], is {gain:.3f} of a white screen's "
            f"at {100 * (1 - OUTLIER_FRACTION):.0f} % of its pixels, fewer than 4 of 256 grey levels (SSIM and PSNR "
            f"would score a constant goal){hint}"
        )
    return gain


def clipped_fraction(goal: torch.Tensor, reflectance: torch.Tensor, ambient: torch.Tensor) -> torch.Tensor:
    """Per image ``(B,)``: the fraction of pixels where some colour of ``goal`` is outside ``[a, a + s]``."""
    rho = reflectance.to(goal).expand_as(goal)
    amb = ambient.to(goal).expand_as(goal)
    out = (goal < amb - RANGE_TOLERANCE) | (goal > amb + rho + RANGE_TOLERANCE)
    return out.any(dim=1).flatten(1).float().mean(dim=1)


def warn_if_out_of_reach(
    goal: Goal, reflectance: torch.Tensor, ambient: torch.Tensor, what: str = "the target"
) -> float:
    """Warn (:class:`SurfaceRangeWarning`) when the surface is too dark for ``what`` (gain below
    :data:`DARK_GAIN`, or more than :data:`WARN_CLIPPED_FRACTION` of its pixels out of reach);
    returns the largest fraction of pixels clipped over the batch."""
    fraction = float(clipped_fraction(goal.image, reflectance, ambient).max())
    gain = float(goal.gain.min())
    if gain < DARK_GAIN or fraction > WARN_CLIPPED_FRACTION:
        warnings.warn(
            f"the surface is too dark for {what}: {100 * fraction:.1f} % of the pixels cannot be reached "
            f"(contrast scaled to {gain:.3f} of a white screen's"
            + ("; SSIM and PSNR are inflated at so low a contrast)" if gain < DARK_GAIN else ")"),
            SurfaceRangeWarning,
            stacklevel=2,
        )
    return fraction
