"""LPIPS: Learned Perceptual Image Patch Similarity (Zhang et al., CVPR 2018), version 0.1.

Both images (RGB in ``[0, 1]``) are mapped to ``[-1, 1]``, shifted and scaled per channel
(``(2x - 1 - shift) / scale``), and passed through an ImageNet backbone (AlexNet or VGG16).
At each of its five tapped layers ``l`` the features are unit-normalized along the channels,

    f_hat = f / (||f||_2 + 1e-10),

and the distance is a weighted squared difference averaged over positions and summed
over layers:

    LPIPS(x, y) = sum_l mean_{h,w} sum_c w_{l,c} (f_hat_x - f_hat_y)^2_{l,c,h,w}

with the published non-negative weights ``w_l`` (the "linear layers"). LPIPS(x, x) = 0.
"""

from __future__ import annotations

import os
from typing import Optional, Sequence

import torch
from torch import nn

from ..errors import EdofprojError
from .backbones import FeatureBackbone, alexnet_backbone, vgg16_backbone
from .weights import backbone_weights_path, load_state_dict_file, metric_weights_path

LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
#: backbone name (torchvision) and constructor of each LPIPS variant
LPIPS_BACKBONES = {"alex": ("alexnet", alexnet_backbone), "vgg": ("vgg16", vgg16_backbone)}
LPIPS_NORM_EPS = 1e-10


class LPIPS(nn.Module):
    """LPIPS distance ``(B,)`` between two batches of RGB images in ``[0, 1]``.

    ``layer_weights``: one non-negative weight vector per tapped backbone layer, its length
    the layer's channel count.
    """

    shift: torch.Tensor  # buffers
    scale: torch.Tensor

    def __init__(self, backbone: FeatureBackbone, layer_weights: Sequence[torch.Tensor]) -> None:
        super().__init__()
        if len(layer_weights) != len(backbone.taps):
            raise EdofprojError(f"LPIPS needs {len(backbone.taps)} layer weight vectors, got {len(layer_weights)}")
        self.backbone = backbone
        for index, weight in enumerate(layer_weights):
            weight = weight.detach().reshape(1, -1, 1, 1).float().clone()
            self.register_buffer(f"layer_weight_{index}", weight)
        self.register_buffer("shift", torch.tensor(LPIPS_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(LPIPS_SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @property
    def layer_weights(self) -> list[torch.Tensor]:
        return [getattr(self, f"layer_weight_{i}") for i in range(len(self.backbone.taps))]

    @classmethod
    def load(cls, net: str = "alex", weights_dir: Optional[str | os.PathLike] = None) -> "LPIPS":
        """LPIPS-``net`` (``alex`` or ``vgg``) with torchvision's backbone and the published
        linear layers. Raises ``PerceptualWeightsMissing`` if a file is absent."""
        if net not in LPIPS_BACKBONES:
            raise EdofprojError(f"unknown LPIPS network '{net}' (allowed: {', '.join(LPIPS_BACKBONES)})")
        backbone_name, make_backbone = LPIPS_BACKBONES[net]
        linear_path = metric_weights_path(f"lpips-{net}", weights_dir)
        backbone_path = backbone_weights_path(backbone_name, weights_dir)
        linear = load_state_dict_file(linear_path)
        keys = [f"lin{i}.model.1.weight" for i in range(5)]
        if any(key not in linear for key in keys):
            raise EdofprojError(f"LPIPS weight file '{linear_path}' lacks the entries {', '.join(keys)}")
        backbone = make_backbone().load_torchvision_weights(backbone_path)
        return cls(backbone, [linear[key] for key in keys])

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """LPIPS per image, shape ``(B,)``."""
        if pred.shape != target.shape or pred.dim() != 4 or pred.shape[1] != 3:
            raise EdofprojError(
                f"LPIPS needs two (B, 3, H, W) batches of the same shape, got "
                f"{tuple(pred.shape)} and {tuple(target.shape)}"
            )
        features_x = self.backbone((2 * pred - 1 - self.shift) / self.scale)
        features_y = self.backbone((2 * target - 1 - self.shift) / self.scale)
        distance = pred.new_zeros(pred.shape[0])
        for fx, fy, weight in zip(features_x, features_y, self.layer_weights):
            fx = fx / (fx.norm(dim=1, keepdim=True) + LPIPS_NORM_EPS)
            fy = fy / (fy.norm(dim=1, keepdim=True) + LPIPS_NORM_EPS)
            distance = distance + ((fx - fy) ** 2 * weight).sum(1).mean((1, 2))
        return distance
