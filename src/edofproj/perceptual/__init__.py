"""Perceptual image distances built on ImageNet networks, without torchvision.

* :mod:`.backbones` - VGG16 / AlexNet feature stacks with torchvision's parameter names.
* :mod:`.dists` - DISTS (Ding et al. 2020).
* :mod:`.lpips` - LPIPS v0.1 (Zhang et al. 2018).
* :mod:`.weights` - locating the weight files; :class:`PerceptualWeightsMissing` when absent.
"""

from .backbones import FeatureBackbone, alexnet_backbone, vgg16_backbone
from .dists import DISTS, L2Pooling, dists_backbone
from .lpips import LPIPS
from .weights import (
    PerceptualWeightsMissing,
    backbone_weights_path,
    hub_checkpoint_dir,
    metric_weights_path,
)

__all__ = [
    "DISTS",
    "LPIPS",
    "FeatureBackbone",
    "L2Pooling",
    "PerceptualWeightsMissing",
    "alexnet_backbone",
    "backbone_weights_path",
    "dists_backbone",
    "hub_checkpoint_dir",
    "metric_weights_path",
    "vgg16_backbone",
]
