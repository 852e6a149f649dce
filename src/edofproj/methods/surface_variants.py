"""A method on a coloured, textured surface: each base method blind and with the photometric correction,
and the surface-aware network.

On a surface of reflectance ``s`` under ambient ``a`` the screen shows ``A(x) = s ⊙ project(x, P_z) + a``
(:mod:`edofproj.imaging.surfaces`); a method is given the goal ``g`` (the target scaled into what the
surface can show, :func:`edofproj.compensation.achievable.achievable_goal`) and the camera's view
``g* = A(g)`` of its uncompensated projection. For each base method ``M`` (:mod:`.builder`):

* ``M`` -- as on a white screen, blind to the texture; ``lens``/``doe``: ``x = g``;
* ``M+photometric`` -- for ``lens``/``doe`` the photometric-only baseline ``x = clip((g - a) / s, 0, 1)``
  (:mod:`edofproj.compensation.photometric`); for a compensating method both in cascade: the network
  (or filter) deblurs the light the photometric correction asks for, ``x = M(D, D*)`` with
  ``D = clip((g - a) / s, 0, 1)`` and ``D* = clip((A(D) - a) / s, 0, 1)`` (the camera's view of ``D``
  projected, divided back: a lab cascade captures it; ``compensate``/``live --surface-from-calib``);
* ``doe+surface-net`` -- a run trained with ``net.surface_input``: its network given the surface,
  ``x = net(g, A(D), s, a)`` (:mod:`edofproj.compensation.surface_net`), as ``compensate`` and ``live``
  run it on a calibration's surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import torch

from ..compensation.photometric import light_for_goal, photometric_compensation
from ..compensation.surface_net import SurfaceAwareNet
from .builder import PreparedMethod
from .designs import OpticalDesign

PHOTOMETRIC = "+photometric"
SURFACE_NET = "doe+surface-net"

#: ``compensate(goal, captured, psf, reflectance, ambient, screen) -> projector input``; ``screen(x) = A(x)``
#: is what the camera sees of ``x`` projected (the cascade captures its own first stage)
SurfaceCompensator = Callable[..., torch.Tensor]


@dataclass
class SurfaceMethod:
    """A method on a textured surface: its name, optical design and compensation (module docstring)."""

    name: str
    design: OpticalDesign
    compensate: SurfaceCompensator


def _blind(method: PreparedMethod) -> SurfaceCompensator:
    return lambda goal, captured, psf, rho, ambient, screen: method.compensate(goal, captured, psf)


def _photometric_only(goal, captured, psf, rho, ambient, screen):
    return photometric_compensation(goal, rho, ambient)


def _cascade(method: PreparedMethod) -> SurfaceCompensator:
    def compensate(goal, captured, psf, rho, ambient, screen):
        light = photometric_compensation(goal, rho, ambient)
        light_captured = light_for_goal(screen(light), rho, ambient).clamp(0.0, 1.0)
        return method.compensate(light, light_captured, psf)

    return compensate


def _surface_net(net: torch.nn.Module) -> SurfaceCompensator:
    def compensate(goal, captured, psf, rho, ambient, screen):
        return net(goal, screen(photometric_compensation(goal, rho, ambient)), rho, ambient)

    return compensate


def surface_methods(prepared: Sequence[PreparedMethod], run_net: torch.nn.Module | None) -> list[SurfaceMethod]:
    """Each base method blind and with the photometric correction, then the surface network if the run has one."""
    methods = []
    for method in prepared:
        if method.spec.compensation == "none":
            methods.append(SurfaceMethod(method.name, method.design, _blind(method)))
            methods.append(SurfaceMethod(method.name + PHOTOMETRIC, method.design, _photometric_only))
        else:
            methods.append(SurfaceMethod(method.name, method.design, _blind(method)))
            methods.append(SurfaceMethod(method.name + PHOTOMETRIC, method.design, _cascade(method)))
    if isinstance(run_net, SurfaceAwareNet):
        run_design = next((m.design for m in prepared if m.spec.optics == "run"), None)
        if run_design is not None:
            methods.append(SurfaceMethod(SURFACE_NET, run_design, _surface_net(run_net.eval())))
    return methods
