"""Weight files in torchvision's format, made by the tests (the real ImageNet weights are not shipped)."""

import torch

# torchvision.models.vgg16().features: (index, out, in) of each 3x3 convolution
VGG16_CONVS = [
    (0, 64, 3),
    (2, 64, 64),
    (5, 128, 64),
    (7, 128, 128),
    (10, 256, 128),
    (12, 256, 256),
    (14, 256, 256),
    (17, 512, 256),
    (19, 512, 512),
    (21, 512, 512),
    (24, 512, 512),
    (26, 512, 512),
    (28, 512, 512),
]
# torchvision.models.alexnet().features: (index, out, in, kernel)
ALEXNET_CONVS = [(0, 64, 3, 11), (3, 192, 64, 5), (6, 384, 192, 3), (8, 256, 384, 3), (10, 256, 256, 3)]


def torchvision_style_state(kind, seed=0):
    """A state dict with torchvision's key names and shapes (random He-initialized weights),
    plus a classifier entry that loaders must ignore."""
    gen = torch.Generator().manual_seed(seed)
    state = {}
    convs = [(i, o, c, 3) for i, o, c in VGG16_CONVS] if kind == "vgg16" else ALEXNET_CONVS
    for index, out_ch, in_ch, k in convs:
        std = (2.0 / (in_ch * k * k)) ** 0.5
        state[f"features.{index}.weight"] = torch.randn(out_ch, in_ch, k, k, generator=gen) * std
        state[f"features.{index}.bias"] = 0.01 * torch.randn(out_ch, generator=gen)
    state["classifier.6.bias"] = torch.zeros(1000)
    return state
