"""The closed loop of compensation: capture, compensate, project (paper Fig. 2).

For a target image ``I`` and a forward model ``A`` (what a screen shows when the projector emits
an image: a flat screen :func:`edofproj.imaging.project`, a depth map
:func:`edofproj.imaging.render_depth_map`, a real projector and camera):

    I*      = observe(A(I))          the uncompensated projection, as the camera records it
    x       = compensate(I, I*)      the projector input a method computes (unclamped)
    display = A(x)                   what the screen shows; scored against I

The projector emits only light in ``[0, 1]``: the forward model clamps its input, and that is the
loop's one clamp. ``clamp(x, 0, 1)`` (:attr:`LoopImages.emitted`) is what is sent to the
projector, the image ``edofproj compensate`` writes. ``observe`` is the camera model (noise,
quantization; the identity by default). Training, fine-tuning, evaluation, tolerance analysis and
``compensate`` all run this one loop; it is differentiable whenever ``A`` and ``compensate`` are.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import torch

from ..imaging.projection import ScreenProjection

#: ``forward(image (B, C, H, W)) -> display (B, C, H, W)``; must clamp its input to [0, 1].
ForwardModel = Callable[[torch.Tensor], torch.Tensor]
#: ``compensate(target, captured) -> projector input``, both ``(B, C, H, W)``.
Compensator = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


class LoopImages(NamedTuple):
    """The images of one pass of the loop, each ``(B, C, H, W)``."""

    captured: torch.Tensor  # I*: the uncompensated projection as observed
    compensated: torch.Tensor  # x: the method's projector input (unclamped)
    projected: torch.Tensor  # A(x): what the screen shows

    @property
    def emitted(self) -> torch.Tensor:
        """``clamp(x, 0, 1)``: the image sent to the projector."""
        return self.compensated.clamp(0.0, 1.0)


def flat_screen(psf: torch.Tensor) -> ForwardModel:
    """The forward model of a flat screen whose PSF is ``psf (B|1, C|1, K, K)``: ``x -> project(x, psf)``
    (the PSF's transfer function computed once for both projections of the loop)."""
    return ScreenProjection(psf)


def scene_screen(cast, psf_for_depths, layers, falloff_reference_m: float | None = None) -> ForwardModel:
    """The forward model of a 3-D scene seen through a ray cast ``cast`` (:class:`~edofproj.scenes.SceneCast`):
    ``x -> render_scene(x, cast, psf_for_depths, layers, falloff_reference_m)`` (it clamps its input)."""
    from ..scenes.render import render_scene  # start-up: trimesh loads only where a scene is rendered

    return lambda image: render_scene(image, cast, psf_for_depths, layers, falloff_reference_m)


def closed_loop(
    target: torch.Tensor,
    forward: ForwardModel,
    compensate: Compensator,
    observe: Callable[[torch.Tensor], torch.Tensor] | None = None,
    captured: torch.Tensor | None = None,
) -> LoopImages:
    """Run ``I* = observe(A(I)); x = compensate(I, I*); display = A(x)`` (module docstring).

    ``captured``, when given, is ``I*`` already at hand (one capture shared by several methods,
    or a camera frame): the capture step is skipped.
    """
    if captured is None:
        captured = forward(target)
        if observe is not None:
            captured = observe(captured)
    compensated = compensate(target, captured)
    return LoopImages(captured, compensated, forward(compensated))
