"""DISTS: Deep Image Structure and Texture Similarity (Ding, Ma, Wang, Simoncelli, TPAMI 2020).

Both images go through VGG16 whose max-pools are replaced by *L2 pooling*,

    L2pool(x) = sqrt(g * x^2)  (stride 2),   g = h h^T / sum(h h^T),  h = (1/2, 1, 1/2),

i.e. a 3×3 Hann window (``numpy.hanning(5)[1:-1]``). Feature maps ``x_j^k`` (stage ``k`` =
the input image and relu1_2, relu2_2, relu3_3, relu4_3, relu5_3; channel ``j``) are compared
by their global statistics:

    l(x, y) = (2 mu_x mu_y + c1) / (mu_x^2 + mu_y^2 + c1)             (texture / "luminance")
    s(x, y) = (2 sigma_xy + c2) / (sigma_x^2 + sigma_y^2 + c2)        (structure)
    DISTS   = 1 - sum_{k,j} (alpha_kj l(x_j^k, y_j^k) + beta_kj s(x_j^k, y_j^k)) / sum(alpha + beta)

with ``c1 = c2 = 1e-6``, means and (biased) variances over the spatial positions, and the
learned non-negative weights ``alpha, beta`` (1475 = 3 + 64 + 128 + 256 + 512 + 512 each).
Images are RGB in ``[0, 1]``; VGG sees them normalized by the ImageNet mean and std.
DISTS(x, x) = 0; larger is more different.
"""

from __future__ import annotations

import os
from typing import Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..errors import EdofprojError
from .backbones import FeatureBackbone, vgg16_backbone
from .weights import backbone_weights_path, load_state_dict_file, metric_weights_path

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: Channels of the compared stages: the image itself, then VGG16's five tapped ReLUs.
DISTS_STAGE_CHANNELS = (3, 64, 128, 256, 512, 512)
#: Indices of the four max-pools inside VGG16's features that DISTS replaces by L2 pooling.
VGG16_POOL_INDICES = (4, 9, 16, 23)
DISTS_EPS = 1e-6


class L2Pooling(nn.Module):
    """``sqrt(conv(x^2, g, stride=2, padding=1) + 1e-12)`` per channel, ``g`` a 3×3 Hann window."""

    window: torch.Tensor  # buffer

    def __init__(self) -> None:
        super().__init__()
        hann = torch.tensor(np.hanning(5)[1:-1], dtype=torch.float32)
        window = torch.outer(hann, hann)
        self.register_buffer("window", (window / window.sum())[None, None], persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        channels = x.shape[1]
        weight = self.window.to(x.dtype).expand(channels, 1, 3, 3)
        pooled = F.conv2d(x * x, weight, stride=2, padding=1, groups=channels)
        return torch.sqrt(pooled + 1e-12)


def dists_backbone() -> FeatureBackbone:
    """VGG16 features with the first four max-pools replaced by :class:`L2Pooling`.

    Parameter names are unchanged (pooling has none), so torchvision's weights still load.
    """
    backbone = vgg16_backbone()
    for index in VGG16_POOL_INDICES:
        backbone.features[index] = L2Pooling()
    return backbone


class DISTS(nn.Module):
    """DISTS distance ``(B,)`` between two batches of RGB images in ``[0, 1]``.

    Differentiable with respect to both inputs (usable as a training loss); the network and
    the alpha/beta weights are frozen.
    """

    alpha: torch.Tensor  # buffers
    beta: torch.Tensor
    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, backbone: FeatureBackbone, alpha: torch.Tensor, beta: torch.Tensor) -> None:
        super().__init__()
        total = sum(DISTS_STAGE_CHANNELS)
        if alpha.numel() != total or beta.numel() != total:
            raise EdofprojError(f"DISTS alpha/beta need {total} weights each, got {alpha.numel()} and {beta.numel()}")
        self.backbone = backbone
        self.register_buffer("alpha", alpha.detach().reshape(total).float().clone())
        self.register_buffer("beta", beta.detach().reshape(total).float().clone())
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def load(cls, weights_dir: Optional[str | os.PathLike] = None) -> "DISTS":
        """DISTS with torchvision's VGG16 weights and the published alpha/beta.

        Raises :class:`~edofproj.perceptual.weights.PerceptualWeightsMissing` if a file is absent.
        """
        alpha_beta_path = metric_weights_path("dists", weights_dir)
        vgg_path = backbone_weights_path("vgg16", weights_dir)
        alpha_beta = load_state_dict_file(alpha_beta_path)
        if "alpha" not in alpha_beta or "beta" not in alpha_beta:
            raise EdofprojError(f"DISTS weight file '{alpha_beta_path}' has no 'alpha'/'beta' entries")
        backbone = dists_backbone().load_torchvision_weights(vgg_path)
        return cls(backbone, alpha_beta["alpha"], alpha_beta["beta"])

    def stage_features(self, images: torch.Tensor) -> list[torch.Tensor]:
        """The image itself followed by the five VGG stages (relu1_2 ... relu5_3)."""
        return [images] + self.backbone((images - self.mean) / self.std)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """DISTS per image, shape ``(B,)``."""
        if pred.shape != target.shape or pred.dim() != 4 or pred.shape[1] != 3:
            raise EdofprojError(
                f"DISTS needs two (B, 3, H, W) batches of the same shape, got "
                f"{tuple(pred.shape)} and {tuple(target.shape)}"
            )
        weight_sum = self.alpha.sum() + self.beta.sum()
        alphas = torch.split(self.alpha / weight_sum, list(DISTS_STAGE_CHANNELS))
        betas = torch.split(self.beta / weight_sum, list(DISTS_STAGE_CHANNELS))
        similarity = pred.new_zeros(pred.shape[0])
        for x, y, alpha, beta in zip(self.stage_features(pred), self.stage_features(target), alphas, betas):
            mu_x, mu_y = x.mean((2, 3)), y.mean((2, 3))
            dx, dy = x - mu_x[..., None, None], y - mu_y[..., None, None]
            var_x, var_y, cov_xy = (dx * dx).mean((2, 3)), (dy * dy).mean((2, 3)), (dx * dy).mean((2, 3))
            texture = (2 * mu_x * mu_y + DISTS_EPS) / (mu_x**2 + mu_y**2 + DISTS_EPS)
            structure = (2 * cov_xy + DISTS_EPS) / (var_x + var_y + DISTS_EPS)
            similarity = similarity + (texture * alpha).sum(1) + (structure * beta).sum(1)
        return 1 - similarity
