"""The display guard: a safe network's output is used only where it is predicted to help.

A safe network (``net.linear_base: ensemble``, :mod:`edofproj.compensation.linear_base`) sends
``x = E(I) + c``: its DOE's depth-ensemble linear filter plus a bounded correction. The bound keeps
the display within ``b`` of the filter's at every pixel, but it does not promise a better image: on
content the training never showed (a fine colour grating, say), ``c`` can make the display worse.
The guard decides, image by image, with the optics the run was designed for and nothing it could
not know (it is as blind as the filter: it never sees the screen's depth):

    S(v) = (1 / |Z|) sum_{z in Z} SSIM( A_z(v), I ),        x_shown = x  if S(x) >= S(E(I))  else  E(I)

``A_z`` the flat-screen projection (:func:`edofproj.imaging.projection.project`) with the design's
PSF at depth ``z``, ``Z`` the near end, the middle in ``1/z`` and the far end of the scored range
(:func:`guard_depths_m`; the depths the training's validation uses). **The rule that makes it
safe:** by construction ``S(x_shown) = max(S(x), S(E(I))) >= S(E(I))`` for every image, so the
guarded network is never behind its own linear filter in mean SSIM over those depths. Over the
other depths of a sweep the guarantee holds as far as three depths stand for the range; the
evaluation reports how often the guard chose the filter.

The cost is two projections and two SSIMs per guard depth: cheap offline and in the evaluation,
too slow for a live loop at 600×800 on a CPU (where the guard is not applied).
"""

from __future__ import annotations

import numpy as np
import torch

from ..compensation.linear_base import LinearBase, ensemble_depths_m
from ..imaging.projection import project
from ..metrics import ssim

#: Number of depths the guard scores: the ends and the middle of the range in 1/z.
GUARD_DEPTHS = 3


def guard_depths_m(near_m: float, far_m: float, count: int = GUARD_DEPTHS) -> np.ndarray:
    """``count`` depths from ``near_m`` to ``far_m`` uniform in ``1/z`` (as the depth-ensemble filter's)."""
    return ensemble_depths_m(near_m, far_m, count)


def predicted_ssim(projector_input: torch.Tensor, target: torch.Tensor, psfs: torch.Tensor) -> torch.Tensor:
    """``S(v)``: mean over the PSFs ``(Z, C, K, K)`` of the SSIM of the flat-screen display of ``v``
    ``(B, C, H, W)`` against ``target``; shape ``(B,)``."""
    scores = [ssim(project(projector_input, psf[None]), target) for psf in psfs]
    return torch.stack(scores).mean(dim=0)


class DisplayGuard:
    """Choose, per image, between a safe network's input ``x`` and its linear filter's ``E(I)``
    (module docstring). ``psfs`` ``(Z, C, K, K)``: the design's PSFs at :func:`guard_depths_m`.

    After each call, ``chose_filter`` holds a ``(B,)`` bool tensor (True where ``E(I)`` was sent)
    and ``margin`` the ``(B,)`` ``S(x) - S(E(I))``; ``filter_count`` / ``calls`` count images.
    """

    def __init__(self, psfs: torch.Tensor) -> None:
        if psfs.ndim != 4:
            raise ValueError(f"guard PSFs must be (Z, C, K, K), got {tuple(psfs.shape)}")
        self.psfs = psfs
        self.chose_filter = torch.zeros(0, dtype=torch.bool)
        self.margin = torch.zeros(0)
        self.filter_count = 0
        self.calls = 0

    @torch.no_grad()
    def __call__(self, target: torch.Tensor, network_input: torch.Tensor, filter_input: torch.Tensor) -> torch.Tensor:
        psfs = self.psfs.to(target.device, target.dtype)
        margin = predicted_ssim(network_input, target, psfs) - predicted_ssim(filter_input, target, psfs)
        chose_filter = margin < 0
        self.chose_filter, self.margin = chose_filter.cpu(), margin.cpu()
        self.filter_count += int(chose_filter.sum())
        self.calls += int(target.shape[0])
        return torch.where(chose_filter.view(-1, 1, 1, 1), filter_input, network_input)


def network_filter(net: torch.nn.Module) -> LinearBase | None:
    """The linear base filter of a safe network, None for any other network."""
    base = getattr(net, "linear_base", None)
    return base if isinstance(base, LinearBase) else None


class GuardedNetworkCompensation:
    """``x_shown`` of :class:`DisplayGuard` for a safe network ``net`` (``compensate(target, captured,
    psf)`` as every evaluation method; ``psf``, the screen's, is not used: the method stays blind)."""

    def __init__(self, net: torch.nn.Module, guard_psfs: torch.Tensor) -> None:
        base = network_filter(net)
        if base is None:
            raise ValueError("the display guard needs a network with a linear base filter (net.linear_base: ensemble)")
        self.net = net.eval()
        self.base = base
        self.guard = DisplayGuard(guard_psfs)

    @torch.no_grad()
    def __call__(self, target, captured, psf):
        x = self.net(target, captured)
        return self.guard(target, x, self.base(target))


def guard_notes(methods) -> list[str]:
    """One note per guarded method of ``methods`` (objects with ``name`` and ``compensate``): in how many
    of the cases it compensated the guard sent the linear filter's input; the counts start again."""
    notes = []
    for method in methods:
        guarded = method.compensate
        if isinstance(guarded, GuardedNetworkCompensation) and guarded.guard.calls:
            guard = guarded.guard
            notes.append(
                f"{method.name}: the display guard sent the linear filter's input instead of the network's in "
                f"{guard.filter_count} of {guard.calls} flat-screen cases (image x depth)"
            )
            guard.filter_count = guard.calls = 0
    return notes
