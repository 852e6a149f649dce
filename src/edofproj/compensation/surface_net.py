"""A compensation network that knows the surface (``net.surface_input: true``).

Any network ``f(I, I*)`` of :mod:`.registry` (the *inner* network: it removes the defocus blur)
is given the surface -- its reflectance ``s`` and ambient ``a``, measured
(:mod:`edofproj.procams.surface`) or drawn in training -- as an extra input:

    D  = clip( (G - a) / s~, 0, 1 )        the light the surface must receive to show the goal G
    D* = clip( (I* - a) / s~, 0, 1 )       the light it received when D was projected
    x0 = f(D, D*)                          deblurred light
    x  = x0 + h([D, D*, s, x0])            projector input (unclamped)

where the capture ``I* = s ⊙ A(D) + a`` is of the photometric correction ``D`` projected (the
uncompensated image of a surface-aware system is its photometric correction, not the raw goal:
the camera sees ``D`` blurred, ``D* = A(D)``, the pair the inner network was built for);

with ``s~ = max(s, 0.02)`` (:mod:`.photometric`) and ``h`` a small full-resolution convolutional
network (3x3, 3x3, 1x1; ``HIDDEN`` channels) whose last layer starts at zero. The order follows the
physics (:mod:`edofproj.imaging.surfaces`): the surface multiplies *after* the blur, so dividing
the goal by the reflectance gives the light to be delivered and the inner network deblurs that;
``h`` sees the texture itself and learns what the division cannot do: where ``D`` clips (dark
spots, bright targets) and where the blurred projection of a texture-corrected image over- or
undershoots at the texture's edges.

Untrained (``h = 0``) the network is the cascade *photometric, then defocus* (the ``both``
baseline, :mod:`edofproj.evaluation.surfaces`); with no surface given (``s = 1, a = 0``) it is the inner network plus ``h``, so it
runs wherever a plain network runs (``net(target, captured)``). The goal ``G`` is the target
scaled into the surface's range (:mod:`.achievable`).
"""

from __future__ import annotations

import torch
from torch import nn

from .photometric import light_for_goal

#: Channels of the surface head ``h``.
HIDDEN = 16


class SurfaceAwareNet(nn.Module):
    """``net(target, captured, reflectance=None, ambient=None) -> projector input`` (module docstring)."""

    def __init__(self, inner: nn.Module, hidden: int = HIDDEN, leaky_slope: float = 0.2) -> None:
        super().__init__()
        self.inner = inner
        self.head = nn.Sequential(
            nn.Conv2d(12, hidden, 3, padding=1, padding_mode="replicate"),
            nn.LeakyReLU(leaky_slope),
            nn.Conv2d(hidden, hidden, 3, padding=1, padding_mode="replicate"),
            nn.LeakyReLU(leaky_slope),
            nn.Conv2d(hidden, 3, 1),
        )
        last = self.head[-1]
        if isinstance(last, nn.Conv2d) and last.bias is not None:
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    def __getattr__(self, name: str):
        # the trainer sets a safe inner network's linear filter and starts a multirate one's linear
        # path through these names (training/linear_filter.py, trainer.start_from_wiener)
        if name in ("linear_base", "initialize_linear_path"):
            return getattr(self.inner, name)
        return super().__getattr__(name)

    def forward(
        self,
        target: torch.Tensor,
        captured: torch.Tensor,
        reflectance: torch.Tensor | None = None,
        ambient: torch.Tensor | None = None,
    ) -> torch.Tensor:
        if reflectance is None:
            reflectance = torch.ones_like(target)
        if ambient is None:
            ambient = torch.zeros((1, target.shape[1], 1, 1), dtype=target.dtype, device=target.device)
        rho = reflectance.to(target).expand_as(target)
        light = light_for_goal(target, rho, ambient).clamp(0.0, 1.0)
        light_captured = light_for_goal(captured, rho, ambient).clamp(0.0, 1.0)
        deblurred = self.inner(light, light_captured)
        features = torch.cat([light, light_captured, rho, deblurred.to(light.dtype)], dim=1)
        return deblurred + self.head(features).to(deblurred.dtype)
