"""The camera that observes the uncompensated projection ``I*`` (the network's second input).

    I*_cam = Q( I* + sigma * n ),    n ~ N(0, 1) per pixel and channel,

where ``Q`` is optional 8-bit quantization, ``Q(x) = round(255 clamp(x, 0, 1)) / 255``. ``Q`` has
zero gradient almost everywhere, so it is applied with a straight-through estimator: the
forward pass uses ``Q(x)``, the backward pass the identity (the DOE still receives gradients
through ``I*``). With ``sigma = 0`` and no quantization the camera is ideal: ``I*_cam = I*``.
"""

from __future__ import annotations

import torch

CAMERA_LEVELS = 255


def quantize_8bit_ste(image: torch.Tensor) -> torch.Tensor:
    """``round(255 clamp(x, 0, 1)) / 255`` forward, identity gradient backward."""
    quantized = torch.round(image.clamp(0.0, 1.0) * CAMERA_LEVELS) / CAMERA_LEVELS
    return image + (quantized - image).detach()


def camera_capture(
    projection: torch.Tensor, noise: torch.Tensor | None = None, sigma: float = 0.0, quantize: bool = False
) -> torch.Tensor:
    """What the camera records of ``projection`` (B, C, H, W); ``noise`` is standard normal, same shape."""
    captured = projection
    if sigma > 0:
        if noise is None or noise.shape != projection.shape:
            raise ValueError("camera_capture needs standard-normal noise of the projection's shape when sigma > 0")
        captured = captured + sigma * noise.to(projection)
    if quantize:
        captured = quantize_8bit_ste(captured)
    return captured
