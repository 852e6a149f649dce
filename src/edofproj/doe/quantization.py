"""Wrapping heights to one wave and quantizing them to N lithography levels.

Wrap:      h_w = h mod h_2pi,      h_2pi = lambda_d / (n(lambda_d) - 1)
Quantize:  h_q = (round(h_w / s) mod N) * s,   s = h_2pi / N

During training the quantizer is a straight-through estimator (STE): the forward pass
uses ``h_q`` and the backward pass the gradient of ``h_w`` (identity), so the optimized and
the evaluated DOE are the same fabricable, quantized one.
"""

from __future__ import annotations

import torch


def wrap_height(height_m: torch.Tensor, h2pi_m: float) -> torch.Tensor:
    """Heights modulo one 2pi wave, in [0, h_2pi). Gradient: identity."""
    return torch.remainder(height_m, h2pi_m)


def quantize_levels(height_m: torch.Tensor, h2pi_m: float, levels: int) -> torch.Tensor:
    """Integer level index in {0, ..., levels-1} of wrapped heights (no gradient)."""
    step = h2pi_m / levels
    return torch.remainder(torch.round(wrap_height(height_m, h2pi_m) / step), levels).long()


def wrap_and_quantize(height_m: torch.Tensor, h2pi_m: float, levels: int | None) -> torch.Tensor:
    """Wrap to [0, h_2pi) and, if ``levels`` is given, quantize with a straight-through estimator."""
    wrapped = wrap_height(height_m, h2pi_m)
    if not levels:
        return wrapped
    quantized = quantize_levels(height_m, h2pi_m, levels).to(wrapped.dtype) * (h2pi_m / levels)
    return wrapped + (quantized - wrapped).detach()
