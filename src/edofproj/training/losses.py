"""Training loss (paper Eq. 12): ``alpha * MSE(pred, target) + beta * D(pred, target)``.

``pred`` is the image the camera sees after compensation, ``target`` the desired image;
both ``(B, 3, H, W)`` in ``[0, 1]``. The perceptual term ``D`` (``loss.perceptual``):

* ``dists`` - DISTS (the paper's choice; needs the VGG16 ImageNet weights, see
  :mod:`edofproj.perceptual.weights`),
* ``ms-ssim`` - ``1 - MS-SSIM`` (weight-free; fewer scales on small crops, see
  :func:`edofproj.metrics.ms_ssim`),
* ``ssim`` - ``1 - SSIM``,
* ``none`` - no perceptual term.

Each term is averaged over the batch. The paper uses ``alpha = 1, beta = 0.05``.
"""

from __future__ import annotations

from typing import Callable, Optional

import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from ..metrics import ms_ssim, ssim
from ..perceptual import DISTS

PERCEPTUAL_TERMS = ("dists", "ms-ssim", "ssim", "none")


def ssim_distance(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``1 - SSIM`` per image, ``(B,)``."""
    return 1 - ssim(pred, target)


def ms_ssim_distance(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``1 - MS-SSIM`` per image, ``(B,)``."""
    return 1 - ms_ssim(pred, target)


class CompensationLoss(nn.Module):
    """``alpha * mean((pred - target)^2) + beta * mean_b D(pred_b, target_b)``.

    ``perceptual`` maps two batches to per-image distances ``(B,)`` (or is ``None``).
    Calling the loss returns the scalar total; :meth:`terms` also returns the parts.
    """

    def __init__(
        self,
        alpha: float = 1.0,
        beta: float = 0.05,
        perceptual: Optional[Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = None,
        perceptual_name: str = "none",
    ) -> None:
        super().__init__()
        if alpha < 0 or beta < 0:
            raise EdofprojError(f"loss weights must be >= 0, got alpha={alpha}, beta={beta}")
        self.alpha = float(alpha)
        self.beta = float(beta)
        self.perceptual = perceptual
        self.perceptual_name = perceptual_name

    def terms(self, pred: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        """``{"mse": ..., "perceptual": ..., "total": ...}`` (scalars; perceptual 0 if unused)."""
        if pred.shape != target.shape:
            raise EdofprojError(
                f"loss needs pred and target of the same shape, got {tuple(pred.shape)} and {tuple(target.shape)}"
            )
        mse = F.mse_loss(pred, target)
        if self.perceptual is not None and self.beta > 0:
            perceptual = self.perceptual(pred, target).mean()
        else:
            perceptual = torch.zeros((), dtype=pred.dtype, device=pred.device)
        return {"mse": mse, "perceptual": perceptual, "total": self.alpha * mse + self.beta * perceptual}

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return self.terms(pred, target)["total"]


def build_loss(loss_cfg) -> CompensationLoss:
    """The loss of a :class:`edofproj.config.LossConfig`.

    ``perceptual=dists`` loads the DISTS network now (raises
    ``PerceptualWeightsMissing`` if its weights are not on this machine), unless ``beta`` is 0.
    """
    name = loss_cfg.perceptual
    if name not in PERCEPTUAL_TERMS:
        raise EdofprojError(f"loss.perceptual='{name}' is not one of {', '.join(PERCEPTUAL_TERMS)}")
    perceptual: Optional[Callable] = None
    if loss_cfg.beta > 0:
        if name == "dists":
            perceptual = DISTS.load(loss_cfg.weights_dir)
        elif name == "ms-ssim":
            perceptual = ms_ssim_distance
        elif name == "ssim":
            perceptual = ssim_distance
    return CompensationLoss(loss_cfg.alpha, loss_cfg.beta, perceptual, name)
