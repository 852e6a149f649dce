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

The guard is part of the shipped method: :class:`GuardedNetwork` is one ``torch.nn.Module``,
``forward(target, captured) -> x_shown``, that ``evaluate`` scores, ``compensate`` and ``live`` run,
``bench`` times and ``export`` writes (its projections are FFTs, so an ONNX export is for one frame
size, as for any network with a Fourier filter). Its cost per frame: the linear filter once more and,
per guard depth, one projection and one SSIM of the network's and the filter's inputs together
(batched; the transfer functions are computed once per frame size, the target's local SSIM
statistics once per frame).
"""

from __future__ import annotations

import numpy as np
import torch

from ..compensation.linear_base import LinearBase, ensemble_depths_m
from ..imaging.projection import ScreenProjection, project
from ..metrics import SSIMReference, ssim

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


def guard_choice(
    target: torch.Tensor, network_input: torch.Tensor, filter_input: torch.Tensor, screens
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(x_shown, margin)`` of the rule in the module docstring: ``margin = S(x) - S(E(I))`` ``(B,)``
    and ``x_shown`` ``(B, C, H, W)`` the network's input where ``margin >= 0``, else the filter's.

    ``screens``: one flat-screen projection ``v -> A_z(v)`` per guard depth (:class:`ScreenProjection`
    or :func:`project` with the depth's PSF). Both inputs go through each screen as one batch."""
    batch = target.shape[0]
    both = torch.cat([network_input, filter_input])
    reference = SSIMReference(target)  # the target's local statistics, filtered once for every screen
    scores = torch.stack([reference.ssim(screen(both)) for screen in screens]).mean(dim=0)
    margin = scores[:batch] - scores[batch:]
    shown = torch.where((margin < 0).view(-1, 1, 1, 1), filter_input, network_input)
    return shown, margin


class GuardedNetwork(torch.nn.Module):
    """A safe network behind its display guard, as one module: ``forward(target, captured) -> x_shown``.

    ``net``: a network with a linear base filter (``net.linear_base``, :class:`LinearBase`);
    ``psfs`` ``(Z, C, K, K)``: its design's PSFs at :func:`guard_depths_m` (a buffer: it moves with
    the module). Inputs and output ``(B, 3, H, W)``; the output is unclamped, as a network's.
    :meth:`decide` also returns the margin ``S(x) - S(E(I))`` per image.
    """

    #: An ONNX export is for one frame size (the guard's projections are FFTs).
    fixed_size_export = True

    def __init__(self, net: torch.nn.Module, psfs: torch.Tensor) -> None:
        super().__init__()
        base = network_filter(net)
        if base is None:
            raise ValueError("the display guard needs a network with a linear base filter (net.linear_base: ensemble)")
        if psfs.ndim != 4:
            raise ValueError(f"guard PSFs must be (Z, C, K, K), got {tuple(psfs.shape)}")
        self.net = net
        self.register_buffer("psfs", psfs.detach().clone())
        self._screens: dict[tuple, list[ScreenProjection]] = {}

    @property
    def linear_base(self) -> LinearBase:
        """The network's linear base filter ``E``."""
        base = network_filter(self.net)
        assert base is not None  # checked in __init__
        return base

    @property
    def channels_last_inputs(self) -> bool:
        """False: ``compensate`` and ``live`` lay the frames out as the evaluation does (contiguous).
        The guard compares two scores that can tie to the last float bit (a barely trained
        correction); the FFTs of another layout differ in those bits and could flip the choice, so
        only the evaluation's layout ships exactly what was scored."""
        return False

    def _screens_for(self, image: torch.Tensor) -> list:
        # contiguous whatever layout the module was moved to: the transfer functions, and with them the
        # choice, are then the evaluation's to the last bit
        psfs: torch.Tensor = self.psfs.contiguous()  # type: ignore[operator]  # a registered buffer
        if torch.jit.is_tracing() or torch.compiler.is_compiling():  # exported: the projections are in the graph
            return [lambda v, psf=psf: project(v, psf[None].to(v.dtype)) for psf in psfs]
        key = (tuple(image.shape[-2:]), image.device, image.dtype)
        if key not in self._screens:
            self._screens = {key: [ScreenProjection(psf[None].to(image.dtype)) for psf in psfs]}
        return self._screens[key]

    def decide(self, target: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(x_shown, margin)`` (:func:`guard_choice`) for the network's input and its filter's."""
        network_input = self.net(target, captured)
        return guard_choice(target, network_input, self.linear_base(target), self._screens_for(target))

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        return self.decide(target, captured)[0]


def network_filter(net: torch.nn.Module) -> LinearBase | None:
    """The linear base filter of a safe network, None for any other network."""
    base = getattr(net, "linear_base", None)
    return base if isinstance(base, LinearBase) else None


class GuardStatistics:
    """How often a guard sent the filter's input: ``chose_filter`` and ``margin`` ``(B,)`` of the last
    call; ``filter_count`` of ``calls`` images since the counts were last reset."""

    def __init__(self) -> None:
        self.chose_filter = torch.zeros(0, dtype=torch.bool)
        self.margin = torch.zeros(0)
        self.filter_count = 0
        self.calls = 0

    def record(self, margin: torch.Tensor) -> None:
        chose_filter = margin < 0
        self.chose_filter, self.margin = chose_filter.cpu(), margin.detach().cpu()
        self.filter_count += int(chose_filter.sum())
        self.calls += int(margin.shape[0])


class DisplayGuard(GuardStatistics):
    """Choose, per image, between two given inputs, the network's ``x`` and its linear filter's ``E(I)``
    (module docstring). ``psfs`` ``(Z, C, K, K)``: the design's PSFs at :func:`guard_depths_m`."""

    def __init__(self, psfs: torch.Tensor) -> None:
        super().__init__()
        if psfs.ndim != 4:
            raise ValueError(f"guard PSFs must be (Z, C, K, K), got {tuple(psfs.shape)}")
        self.psfs = psfs

    @torch.no_grad()
    def __call__(self, target: torch.Tensor, network_input: torch.Tensor, filter_input: torch.Tensor) -> torch.Tensor:
        psfs = self.psfs.to(target.device, target.dtype)
        screens = [ScreenProjection(psf[None]) for psf in psfs]
        shown, margin = guard_choice(target, network_input, filter_input, screens)
        self.record(margin)
        return shown


class GuardedNetworkCompensation:
    """A :class:`GuardedNetwork` as a method's compensation, ``compensate(target, captured, psf)`` (``psf``,
    the screen's, is not used: the method stays blind); ``guard`` counts how often the filter was sent."""

    def __init__(self, net: torch.nn.Module, guard_psfs: torch.Tensor) -> None:
        self.module = GuardedNetwork(net, guard_psfs).eval()
        self.net = self.module.net
        self.guard = GuardStatistics()

    @torch.no_grad()
    def __call__(self, target, captured, psf=None):
        shown, margin = self.module.decide(target, captured)
        self.guard.record(margin)
        return shown


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
