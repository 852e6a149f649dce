"""Compensation of the blur a PSF map measured: the projector image whose blurred projection looks
like the target, for the ``wiener`` and ``cls`` methods of ``edofproj compensate --psf-map``.

The blur is :func:`.measured_blur.measured_blur` (one kernel per node of the projector image, each
colour its own map where the file has one). The methods are those of
:mod:`edofproj.compensation.field_varying`:

* ``wiener``: the field-varying Wiener filter. Its NSR is chosen as the spatially invariant filter's
  (:func:`edofproj.compensation.wiener.tune_wiener_nsr`, SSIM of the compensated projection on
  training crops of the built-in photographs, never the target), over the kernels of five nodes
  (the corners and the centre): one NSR for the whole map;
* ``cls``: box-constrained least squares ``min ||A x - t||^2, 0 <= x <= 1`` with the exact operator,
  ``iterations`` steps of a solver of
  :func:`edofproj.compensation.field_varying.field_varying_cls` (the projected quasi-Newton ``lbfgs`` by
  default, or monotone FISTA) from the ``wiener`` estimate (its NSR tuned as above, or given);
  the objective at every step is returned, so a caller can say how far it went.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.field_varying import FieldVaryingBlur

MAP_METHODS = ("wiener", "cls")
"""The methods computed from the map alone (``net`` needs a fine-tuned run)."""
NSR_TUNING_CROPS = 8
"""Training crops the NSR is tuned on."""


@dataclass
class MapCompensation:
    """What one compensation did: the projector image ``image (B, C, H, W)`` in [0, 1], the method,
    the Wiener NSR, the blur's rank (convolutions per application), the CLS objective per iteration
    ``objective (iterations + 1, B)`` (empty for ``wiener``) and the seconds it took (the Wiener
    filter's set-up included unless it was given; the blur's and the NSR's excluded)."""

    image: torch.Tensor
    method: str
    nsr: float
    rank: int
    seconds: float
    objective: torch.Tensor = field(default_factory=lambda: torch.zeros(0))

    def convergence(self) -> str:
        """One line: the CLS objective's decrease over the last tenth of the iterations, relative to
        its total decrease (small: converged for that start)."""
        f = self.objective
        if f.numel() == 0 or f.shape[0] < 2:
            return "no iterations"
        total = float((f[0] - f[-1]).sum())
        tail = float((f[-1 - max((f.shape[0] - 1) // 10, 1)] - f[-1]).sum())
        share = tail / total if total > 0 else 0.0
        return (
            f"objective {float(f[0].sum()):.4g} -> {float(f[-1].sum()):.4g} in {f.shape[0] - 1} iterations; "
            f"the last tenth gained {100 * share:.2f} % of the decrease"
        )


def representative_kernels(op: FieldVaryingBlur, channels: int = 3) -> torch.Tensor:
    """``(5, C, K, K)``: the node kernels at the image's four corners and its centre, per colour (a
    one-channel blur's kernels repeated to ``channels``)."""
    gy, gx = op.kernels.shape[:2]
    picks = [op.kernels[i, j] for i, j in ((0, 0), (0, gx - 1), (gy // 2, gx // 2), (gy - 1, 0), (gy - 1, gx - 1))]
    kernels = torch.stack(picks).to(torch.float32)
    return kernels.expand(-1, channels, -1, -1) if kernels.shape[1] == 1 else kernels


def tune_map_nsr(op: FieldVaryingBlur, seed: int = 0) -> float:
    """The NSR of the module docstring (``wiener``): SSIM-tuned on training crops, over five of the map's kernels."""
    from ..compensation.wiener import tune_wiener_nsr
    from ..config import DataConfig
    from ..data.sources import build_training_source
    from ..imaging.projection import project
    from ..metrics import ssim

    source = build_training_source(DataConfig(), seed)
    crops = source.sample(
        NSR_TUNING_CROPS, max(DataConfig().crop, 4 * op.kernels.shape[-1]), torch.Generator().manual_seed(seed)
    )
    nsr, _ = tune_wiener_nsr(crops, representative_kernels(op), project, metric=ssim)
    return float(nsr)


def compensate_with_map(
    target: torch.Tensor,
    op: FieldVaryingBlur,
    method: str,
    nsr: float | None = None,
    iterations: int | None = None,
    wiener=None,
    solver: str | None = None,
) -> MapCompensation:
    """The projector image for ``target (B, C, H, W)`` in [0, 1] under the blur ``op``, by ``method``
    (``wiener`` or ``cls``; module docstring). ``nsr``: the Wiener NSR (default tuned, :func:`tune_map_nsr`);
    ``iterations``: CLS iterations (default
    :data:`edofproj.compensation.field_varying.DEFAULT_CLS_ITERATIONS`); ``wiener``: a
    :class:`~edofproj.compensation.field_varying.FieldVaryingWiener` of ``op`` set up before (for
    several images; its NSR is then the one used); ``solver``: ``cls``'s, one of
    :data:`edofproj.compensation.field_varying.CLS_METHODS` (default
    :data:`~edofproj.compensation.field_varying.DEFAULT_CLS_SOLVER`)."""
    from ..compensation.field_varying import (
        DEFAULT_CLS_ITERATIONS,
        DEFAULT_CLS_SOLVER,
        FieldVaryingWiener,
        field_varying_cls,
    )

    if method not in MAP_METHODS:
        raise EdofprojError(f"unknown method '{method}' for a PSF map (known: {', '.join(MAP_METHODS)})")
    if tuple(target.shape[-2:]) != (op.height, op.width):
        raise EdofprojError(
            f"the image is {target.shape[-2]}x{target.shape[-1]} px but the PSF map's projector "
            f"{op.height}x{op.width} (height x width)"
        )
    iterations = DEFAULT_CLS_ITERATIONS if iterations is None else int(iterations)
    if iterations < 0:
        raise EdofprojError(f"iterations={iterations} must be >= 0")
    if wiener is not None:
        nsr = wiener.nsr
    nsr = tune_map_nsr(op) if nsr is None else float(nsr)
    if not (np.isfinite(nsr) and nsr >= 0):
        raise EdofprojError(f"NSR={nsr} must be a finite number >= 0")
    start = time.perf_counter()
    with torch.no_grad():
        x = (wiener or FieldVaryingWiener(op, nsr))(target)
        objective = torch.zeros(0)
        if method == "cls":
            x, objective = field_varying_cls(
                target, op, iterations, start=x, method=solver or DEFAULT_CLS_SOLVER, return_objective=True
            )
    return MapCompensation(x, method, nsr, op.rank, time.perf_counter() - start, objective)
