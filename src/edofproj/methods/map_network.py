"""A run's network compensating the blur of a PSF map (``edofproj compensate --psf-map MAP --method net``).

The network computes ``x = net(I, I*)`` from the target ``I`` and its uncompensated projection ``I*``
(:mod:`edofproj.compensation.closed_loop`); here ``I*`` is the projection the PSF map predicts,
``I* = A clamp(I, 0, 1)`` with ``A`` the map's field-varying blur
(:func:`edofproj.procams.measured_blur.measured_blur`). A run fine-tuned on the map
(``edofproj finetune RUN --psf-map MAP``) has learnt the map's kernels; any other run's network is
run as it is. The output is clamped to ``[0, 1]``.
"""

from __future__ import annotations

import torch

from ..errors import EdofprojError
from ..imaging.field_varying import FieldVaryingBlur
from ..runs import load_run


class MapNetwork:
    """``MapNetwork(run_dir, op)(target (B, 3, H, W)) -> x (B, 3, H, W)`` in [0, 1] (module docstring)."""

    def __init__(self, run_dir, op: FieldVaryingBlur) -> None:
        trained = load_run(run_dir)
        if getattr(trained.cfg.net, "surface_input", False):
            raise EdofprojError(
                f"the network of '{run_dir}' takes a measured surface (net.surface_input): not one for a PSF map"
            )
        self.net = trained.net.eval()
        self.op = op

    def __call__(self, target: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            captured = self.op(target.clamp(0.0, 1.0))
            return self.net(target, captured).clamp(0.0, 1.0)
