"""ImageNet feature extractors (VGG16, AlexNet) in plain PyTorch, without torchvision.

Each backbone holds an ``nn.Sequential`` called ``features`` whose layer indices, parameter
names and shapes are exactly those of ``torchvision.models.<name>().features``, so
torchvision's weight files (``features.0.weight``, ``features.0.bias``, ...) load directly;
their ``classifier.*`` entries are ignored.

``forward(x)`` returns the activations after the ReLUs listed in ``taps`` (the layers that
LPIPS and DISTS compare). Inputs are already normalized by the caller (each metric has its
own normalization). Parameters are frozen: gradients flow to the input only.
"""

from __future__ import annotations

import itertools
import os
from typing import Sequence

import torch
from torch import nn

from ..errors import EdofprojError
from .weights import load_state_dict_file

#: torchvision's VGG16 configuration "D": channel counts, "M" = 2×2 max-pool.
VGG16_LAYOUT = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")
#: Indices of relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 in ``vgg16().features``.
VGG16_TAPS = (3, 8, 15, 22, 29)
#: Indices of the five ReLUs in ``alexnet().features``.
ALEXNET_TAPS = (1, 4, 7, 9, 11)


def vgg16_feature_layers() -> nn.Sequential:
    """``torchvision.models.vgg16().features``: 13 3×3 convolutions (padding 1) with ReLUs and
    five 2×2 max-pools, 31 modules indexed 0-30."""
    layers: list[nn.Module] = []
    channels = 3
    for item in VGG16_LAYOUT:
        if item == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            width = int(item)
            layers += [nn.Conv2d(channels, width, kernel_size=3, padding=1), nn.ReLU(inplace=False)]
            channels = width
    return nn.Sequential(*layers)


def alexnet_feature_layers() -> nn.Sequential:
    """``torchvision.models.alexnet().features`` (the one-GPU "OWT" variant), indices 0-12."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(384, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(256, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


class FeatureBackbone(nn.Module):
    """A frozen feature stack ``features`` that returns the activations at ``taps``."""

    def __init__(self, features: nn.Sequential, taps: Sequence[int], name: str) -> None:
        super().__init__()
        self.features = features
        self.taps = tuple(taps)
        self.name = name
        self.requires_grad_(False)
        self.eval()

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Activations after each layer index in ``taps`` (layers past the last tap skipped)."""
        outputs = []
        for index, layer in enumerate(itertools.islice(self.features, self.taps[-1] + 1)):
            x = layer(x)
            if index in self.taps:
                outputs.append(x)
        return outputs

    def load_torchvision_state_dict(self, state: dict, source: str = "state dict") -> None:
        """Load the ``features.*`` entries of a torchvision state dict (other keys ignored).

        Raises :class:`~edofproj.errors.EdofprojError` when an entry is missing or has the
        wrong shape (a file for another architecture).
        """
        expected = self.state_dict()
        selected = {key: value for key, value in state.items() if key in expected}
        missing = sorted(set(expected) - set(selected))
        if missing:
            raise EdofprojError(
                f"{source} is not a torchvision {self.name} weight file: missing {', '.join(missing[:3])}"
                + (" ..." if len(missing) > 3 else "")
            )
        for key, value in selected.items():
            if tuple(value.shape) != tuple(expected[key].shape):
                raise EdofprojError(
                    f"{source}: '{key}' has shape {tuple(value.shape)}, {self.name} needs {tuple(expected[key].shape)}"
                )
        self.load_state_dict(selected, strict=True)

    def load_torchvision_weights(self, path: str | os.PathLike) -> "FeatureBackbone":
        """Load torchvision's weight file at ``path`` (e.g. ``vgg16-397923af.pth``)."""
        self.load_torchvision_state_dict(load_state_dict_file(path), source=f"'{path}'")
        return self


def vgg16_backbone() -> FeatureBackbone:
    """VGG16 features tapped at relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 (random weights)."""
    return FeatureBackbone(vgg16_feature_layers(), VGG16_TAPS, "vgg16")


def alexnet_backbone() -> FeatureBackbone:
    """AlexNet features tapped at its five ReLUs (random weights)."""
    return FeatureBackbone(alexnet_feature_layers(), ALEXNET_TAPS, "alexnet")
