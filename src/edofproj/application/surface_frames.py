"""Compensation of one lab frame on a measured coloured, textured surface.

A calibration with the surface (``procams calibrate --surface-captures``) holds, per projector
pixel, the reflectance ``s`` and the ambient ``a`` (:mod:`edofproj.procams.surface`), in absolute
projector output units: what the camera sees of a projected light ``L`` is
``c = M^-1 c_cam(q(x)) = s ⊙ (PSF ⊛ L) + a``. For a target ``t`` (projector output light):

    g  = f + k t                                  the goal: t scaled into [a, a + s]
                                                  (:func:`~edofproj.compensation.achievable.achievable_goal`)
    D  = clip( (g - a) / s~, 0, 1 )                the photometric correction
                                                  (:func:`~edofproj.compensation.photometric.photometric_compensation`)

The uncompensated image of a surface-aware system is ``D`` (not the raw target): the lab projects
``u0 = f^-1(D)`` (:func:`photometric_input`) and captures it, ``I* = s ⊙ A(D) + a``. Then

* a surface-aware network (``net.surface_input``, :class:`~edofproj.compensation.surface_net.SurfaceAwareNet`):
  ``x = net(g, I*, s, a)``, as it was trained and is evaluated;
* any other network, in cascade (*photometric, then defocus*): ``x = net(D, clip((I* - a) / s~, 0, 1))``.

The projector input is ``u = f^-1(clip(x, 0, 1))`` (the inverse of the measured response).
Tensors ``(B, 3, H, W)`` at the calibrated projector's size; captures ``(Hc, Wc, 3)`` raw camera RGB.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import torch

from ..compensation.achievable import Goal, achievable_goal, require_visible, warn_if_out_of_reach
from ..compensation.photometric import light_for_goal, photometric_compensation
from ..compensation.surface_net import SurfaceAwareNet
from ..procams.calibration import ProCamsCalibration
from ..procams.surface import SURFACE_HINT


class MeasuredSurface(NamedTuple):
    """The calibration's surface as tensors: ``reflectance (1, 3, H, W)``, ``ambient (1, 3, H, W)``."""

    reflectance: torch.Tensor
    ambient: torch.Tensor


def measured_surface(calibration: ProCamsCalibration, what: str = "this command") -> MeasuredSurface:
    """The calibration's measured surface, or one line saying that it was made without the surface
    captures or that the surface cannot show an image (:func:`~edofproj.compensation.achievable.require_visible`:
    ``compensate`` and ``live`` refuse what ``evaluate --surface`` refuses)."""
    rho, ambient = calibration.require_surface(what)
    surface = MeasuredSurface(
        torch.from_numpy(np.ascontiguousarray(rho.transpose(2, 0, 1)))[None].float(),
        torch.from_numpy(np.ascontiguousarray(ambient.transpose(2, 0, 1)))[None].float(),
    )
    require_visible(*surface, "the surface measured in the calibration", SURFACE_HINT)
    return surface


def surface_goal(target: torch.Tensor, surface: MeasuredSurface, what: str = "the target") -> Goal:
    """The goal ``g = f + k t`` of ``target`` on the surface; warns when the surface is too dark for it."""
    goal = achievable_goal(target, surface.reflectance, surface.ambient)
    warn_if_out_of_reach(goal, surface.reflectance, surface.ambient, what=what)
    return goal


def photometric_input(
    target: torch.Tensor, calibration: ProCamsCalibration, surface: MeasuredSurface, what: str = "the target"
) -> torch.Tensor:
    """``u0 = f^-1(D)``: the projector input of the photometric correction of ``target`` -- the
    photometric-only compensation, and what the lab projects and captures for the networks."""
    goal = surface_goal(target, surface, what)
    return calibration.to_projector_input(photometric_compensation(goal.image, *surface))


def compensate_on_surface(
    net: Callable[..., torch.Tensor],
    target: torch.Tensor,
    capture: np.ndarray,
    calibration: ProCamsCalibration,
    surface: MeasuredSurface,
    what: str = "the target",
) -> torch.Tensor:
    """The projector input ``u = f^-1(clip(x, 0, 1))`` for ``target (1, 3, H, W)`` from the raw
    ``capture`` of its photometric correction projected (module docstring); ``net`` in inference mode."""
    goal = surface_goal(target, surface, what)
    absolute = calibration.to_absolute_output(capture)
    captured = torch.from_numpy(absolute.astype(np.float32).transpose(2, 0, 1).copy())[None]
    rho, ambient = surface
    with torch.inference_mode():
        if isinstance(net, SurfaceAwareNet):
            x = net(goal.image, captured, rho, ambient)
        else:
            light = photometric_compensation(goal.image, rho, ambient)
            x = net(light, light_for_goal(captured, rho, ambient).clamp(0.0, 1.0))
    return calibration.to_projector_input(x.clamp(0.0, 1.0))


class SurfaceLoop:
    """What ``live`` (:mod:`.live`) needs to compensate on the calibration's surface, frame after frame.

    Per target: the goal ``g``, the photometric correction ``D`` (what is shown first, as
    ``f^-1(D)``) and the network's first input (``g`` for a surface-aware network, ``D`` in cascade);
    per frame: the rectified capture ``M^-1 (c - c_black)`` plus :attr:`offset` ``= M^-1 c_black(q(x))``
    is the absolute light ``I*`` the surface's ambient is measured in (module docstring).
    """

    def __init__(self, calibration: ProCamsCalibration, net: Callable[..., torch.Tensor], what: str = "live") -> None:
        self.aware = isinstance(net, SurfaceAwareNet)
        self.surface = measured_surface(calibration, what)
        black = calibration.color.camera_to_output(calibration.black_image, np.zeros(3)).astype(np.float32)
        self.offset_hwc = black
        self.offset = torch.from_numpy(np.ascontiguousarray(black.transpose(2, 0, 1)))[None]

    def prepare(
        self, target: torch.Tensor, what: str = "the target", warn: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(network input, light to show)`` for ``target (B, 3, H, W)``: ``(g or D, D)``."""
        if warn:
            goal = surface_goal(target, self.surface, what).image
        else:
            goal = achievable_goal(target, *self.surface).image
        light = photometric_compensation(goal, *self.surface)
        return (goal if self.aware else light), light

    def goal(self, target: torch.Tensor) -> torch.Tensor:
        """The goal ``g`` of ``target (1, 3, H, W)``, the reference a capture on the surface is scored against."""
        return achievable_goal(target, *self.surface).image

    def compensate(
        self, net: Callable[..., torch.Tensor], light: torch.Tensor, rectified: torch.Tensor
    ) -> torch.Tensor:
        """``x`` (module docstring) from the network input of :meth:`prepare` and the rectified capture."""
        return self.compensate_absolute(net, light, rectified + self.offset)

    def compensate_absolute(
        self, net: Callable[..., torch.Tensor], light: torch.Tensor, captured: torch.Tensor
    ) -> torch.Tensor:
        """``x`` from the network input of :meth:`prepare` and the capture as absolute light ``I*``."""
        rho, ambient = self.surface
        if self.aware:
            return net(light, captured, rho, ambient)
        return net(light, light_for_goal(captured, rho, ambient).clamp(0.0, 1.0))
