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

**Tiles.** ``S`` is a mean of a local SSIM map. On a frame large enough (:func:`guard_tiles`: a
600x800 frame with the ``cpu`` preset's 33-px PSFs) :class:`GuardedNetwork` estimates it on a few
tiles of that map, spread over the frame: the same local values at ``n T^2`` of its positions
(:func:`tiled_guard_choice`), for :data:`GUARD_WORK_FRACTION` of the whole frame's FFT work. The rule
above then holds for the tiled score: ``S_tiles(x_shown) >= S_tiles(E(I))``; where the tiles' sample
and the whole map disagree on the sign of the margin, the decision differs from the whole frame's
(measured on the test and the validation images at the scored depths by ``benchmarks/guard_cost.py
--agreement``; docs/experiments/2026-11-29-cheap-guard-and-1080p-export.md). A smaller frame is scored
whole (:func:`guard_choice`).

The guard is part of the shipped method: :class:`GuardedNetwork` is one ``torch.nn.Module``,
``forward(target, captured) -> x_shown``, that ``evaluate`` scores, ``compensate`` and ``live`` run,
``bench`` times and ``export`` writes (its projections are FFTs, so an ONNX export is for one frame
size, as for any network with a Fourier filter). Its cost per frame: the network's own output of
the linear filter is kept (not computed again) and, per guard depth, one projection and one SSIM of
the network's and the filter's inputs together (batched), on the tiles or the whole frame.
"""

from __future__ import annotations

import numpy as np
import torch

from ..compensation.linear_base import LinearBase, ensemble_depths_m
from ..imaging.convolution import (
    apply_matrix_transfer_function,
    fast_fft_length,
    fft_shape,
    matrix_transfer_function,
    optical_transfer_function,
)
from ..imaging.projection import ScreenProjection, project
from ..metrics import SSIMReference, gaussian_window, ssim

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


#: A tiled margin ``|S_tiles(x) - S_tiles(E(I))|`` below this is decided on the whole frame instead
#: (:meth:`GuardedNetwork.decide`): on the validation and test images at 600x800 every tiled decision
#: that differed from the whole frame's had a tiled margin of at most 5.6e-4
#: (docs/experiments/2026-11-29-cheap-guard-and-1080p-export.md).
GUARD_MARGIN_BAND = 1e-3

#: Side (px) of one square tile of the SSIM map that the tiled decision scores (:func:`guard_tiles`).
GUARD_TILE_PX = 32

#: The tiled decision's FFT work as a fraction of the exact one's (its tiles' FFT grids against the
#: whole frame's): it sets the number of tiles. A frame where not one tile fits this budget is small
#: enough to be scored whole.
GUARD_WORK_FRACTION = 0.15


def guard_tiles(
    height: int, width: int, psf_px: int, tile_px: int = GUARD_TILE_PX, work_fraction: float = GUARD_WORK_FRACTION
) -> list[tuple[int, int]]:
    """Top-left corners ``(row, column)`` in the SSIM map of the tiles the tiled decision scores;
    empty when the frame is scored whole.

    The SSIM map of an ``H x W`` frame is ``(H - 2r) x (W - 2r)`` (``r`` the Gaussian window's
    radius); its value at ``(i, j)`` needs the display's pixels ``i .. i + 2r`` (rows) and, through a
    ``K x K`` PSF, the projector input's pixels ``i - K//2 .. i + 2r + K//2``. A tile of ``T x T`` map
    values thus costs one FFT grid of ``fast(T + 2r + 2 (K//2))`` pixels a side per image and depth,
    against ``fft_shape(H, W)`` for the whole frame: ``n = floor(work_fraction * whole / tile)``
    tiles, on a ``rows x cols`` grid of the map's aspect, each centred in its cell (spread over the
    frame, never overlapping). ``n < 1`` (a small frame) or a map smaller than a tile: ``[]``."""
    radius = gaussian_window().numel() // 2
    map_h, map_w = int(height) - 2 * radius, int(width) - 2 * radius
    if map_h < tile_px or map_w < tile_px:
        return []
    whole = fft_shape((int(height), int(width)), (int(psf_px), int(psf_px)))
    tile_grid = fast_fft_length(tile_px + 2 * radius + 2 * (int(psf_px) // 2))
    count = int(work_fraction * whole[0] * whole[1]) // tile_grid**2
    if count < 1:
        return []
    rows = min(max(1, round(float(np.sqrt(count * map_h / map_w)))), map_h // tile_px)
    cols = min(max(1, count // rows), map_w // tile_px)
    tops = [int((i + 0.5) * map_h / rows - tile_px / 2) for i in range(rows)]
    lefts = [int((j + 0.5) * map_w / cols - tile_px / 2) for j in range(cols)]
    return [(top, left) for top in tops for left in lefts]


def tiled_guard_choice(
    target: torch.Tensor,
    network_input: torch.Tensor,
    filter_input: torch.Tensor,
    psfs: torch.Tensor,
    tiles: list[tuple[int, int]],
    tile_px: int = GUARD_TILE_PX,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`guard_choice` with ``S`` estimated on ``tiles`` (:func:`guard_tiles`) of the SSIM map.

    ``S_tiles(v)`` is the mean of the *same* local SSIM values as ``S(v)``'s, at the tiles' ``n T^2``
    positions only (one sample of the map): each tile's display is the flat-screen projection of a
    crop of ``v`` with a margin of ``K//2`` (zeros beyond the frame, as the projection's own
    padding), a circular convolution on the crop's FFT grid whose wrap stays in the margin, plus the
    haze ``(1 - sum p) mean(clamp(v))`` of the *whole* frame (``imaging.projection``). The rule is
    the guard's: ``x`` where ``S_tiles(x) >= S_tiles(E(I))``, else ``E(I)``; ``margin`` is
    ``S_tiles(x) - S_tiles(E(I))`` ``(B,)``. ``psfs`` ``(Z, C, K, K)``. The forward transform of the
    crops is shared by the depths; exported (ONNX), the transforms are matrix products."""
    batch = target.shape[0]
    radius = gaussian_window().numel() // 2
    margin_px = psfs.shape[-1] // 2
    side = tile_px + 2 * radius  # display pixels under one tile's SSIM windows
    crop = side + 2 * margin_px
    grid = (fast_fft_length(crop), fast_fft_length(crop))
    height, width = target.shape[-2:]
    pieces = []
    for image in (network_input, filter_input):
        for top, left in tiles:  # the crop of the frame zero-padded by K//2, without padding the frame
            rows, cols = (top - margin_px, top - margin_px + crop), (left - margin_px, left - margin_px + crop)
            piece = image[..., max(rows[0], 0) : min(rows[1], height), max(cols[0], 0) : min(cols[1], width)]
            pad = (max(-cols[0], 0), max(cols[1] - width, 0), max(-rows[0], 0), max(rows[1] - height, 0))
            pieces.append(torch.nn.functional.pad(piece, pad) if any(pad) else piece)
    count = len(tiles)
    crops = torch.stack(pieces, dim=1).clamp(0.0, 1.0)  # (B, 2n, C, S, S)
    crops = crops.view(batch, 2, count, *crops.shape[2:]).transpose(0, 1)  # (2, B, n, C, S, S)
    kernels = psfs.to(target.dtype)[:, None, None, None]  # (Z, 1, 1, 1, C, K, K)
    if torch.onnx.is_in_onnx_export():
        convolved = apply_matrix_transfer_function(crops, matrix_transfer_function(kernels, grid), grid)
    else:
        spectrum = torch.fft.rfft2(crops, s=grid)  # once for every depth
        convolved = torch.fft.irfft2(spectrum * optical_transfer_function(kernels, grid), s=grid)
    inner = convolved[..., margin_px : margin_px + side, margin_px : margin_px + side]  # (Z, 2, B, n, C, s, s)
    lost = 1.0 - psfs.to(target.dtype).sum(dim=(-1, -2))  # (Z, C)
    means = torch.stack([v.clamp(0.0, 1.0).mean(dim=(-1, -2)) for v in (network_input, filter_input)])  # (2, B, C)
    haze = lost[:, None, None, None, :, None, None] * means[None, :, :, None, :, None, None]
    displays = inner + haze  # (Z, 2, B, n, C, s, s)
    depths, channels = psfs.shape[0], target.shape[1]
    target_tiles = torch.stack([target[..., t : t + side, c : c + side] for t, c in tiles], dim=1)
    reference = SSIMReference(target_tiles.reshape(batch * count, channels, side, side))
    local = reference.maps(displays.reshape(depths * 2 * batch * count, channels, side, side))[0]
    scores = local.reshape(depths, 2, batch, -1).mean(dim=(0, 3))  # (2, B): mean over depths, tiles, pixels
    margin = scores[0] - scores[1]
    if batch == 1 and not (torch.jit.is_tracing() or torch.compiler.is_compiling()):
        return (filter_input if bool(margin[0] < 0) else network_input), margin  # one frame: no copy
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
        #: The tiled decision's tile side and work budget (:func:`guard_tiles`).
        self.tile_px = GUARD_TILE_PX
        self.work_fraction = GUARD_WORK_FRACTION

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

    def _network_and_filter(self, target: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(x, E(I))``: the network's input and its filter's. The network filters the target itself
        (``x = E(I) + c``); that output is kept (a forward hook) rather than computed again. Traced for
        an export, the filter is called again: the exporter's common-subexpression pass makes it one."""
        base = self.linear_base
        if torch.jit.is_tracing() or torch.compiler.is_compiling():
            return self.net(target, captured), base(target)
        kept: list[torch.Tensor] = []

        def keep(module, args, output) -> None:
            if args and args[0] is target:
                kept.append(output)

        handle = base.register_forward_hook(keep)
        try:
            network_input = self.net(target, captured)
        finally:
            handle.remove()
        return network_input, kept[0] if len(kept) == 1 else base(target)

    def tiles_for(self, height: int, width: int) -> list[tuple[int, int]]:
        """The tiles the decision scores at ``height x width`` (:func:`guard_tiles`; ``[]``: the whole frame)."""
        psfs: torch.Tensor = self.psfs  # type: ignore[assignment]  # a registered buffer
        return guard_tiles(height, width, int(psfs.shape[-1]), self.tile_px, self.work_fraction)

    def decide(self, target: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(x_shown, margin)`` for the network's input and its filter's: :func:`tiled_guard_choice` on
        :meth:`tiles_for` the frame; :func:`guard_choice` (the whole frame) where it has no tiles, or
        where a tiled margin is within :data:`GUARD_MARGIN_BAND` of zero (the sample too close to a tie
        to stand for the whole map: the whole frame decides; a batch, all of it). Traced (TorchScript),
        the graph computes both margins and chooses as this does; an ONNX file runs the whole frame's
        decision in a branch (:meth:`export_parts`)."""
        network_input, filter_input = self._network_and_filter(target, captured)
        tiles = self.tiles_for(target.shape[-2], target.shape[-1])
        screens = self._screens_for(target)
        if not tiles:
            return guard_choice(target, network_input, filter_input, screens)
        psfs: torch.Tensor = self.psfs.contiguous()  # type: ignore[operator]  # a registered buffer
        shown, margin = tiled_guard_choice(target, network_input, filter_input, psfs, tiles, self.tile_px)
        near_tie = (margin.abs() < GUARD_MARGIN_BAND).any()
        if torch.jit.is_tracing() or torch.compiler.is_compiling():  # exported: both margins, one chosen
            margin = torch.where(near_tie, guard_choice(target, network_input, filter_input, screens)[1], margin)
            return torch.where((margin < 0).view(-1, 1, 1, 1), filter_input, network_input), margin
        if bool(near_tie):
            return guard_choice(target, network_input, filter_input, screens)
        return shown, margin

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        return self.decide(target, captured)[0]

    def export_parts(self, height: int, width: int) -> tuple[torch.nn.Module, torch.nn.Module, torch.nn.Module] | None:
        """:meth:`decide` at ``height x width`` as three modules for an ONNX file with the whole frame's
        decision in a branch (an ``If`` node, :func:`edofproj.compensation.export.export_network`):

        * head ``(target, captured) -> (x, E(I), tiled margin, near_tie)``;
        * branch ``(target, x, E(I)) -> margin`` of the whole frame (:func:`guard_choice`), run only
          where ``near_tie`` (:data:`GUARD_MARGIN_BAND`);
        * tail ``(x, E(I), margin) -> x_shown``.

        None where the frame has no tiles (it is decided whole: there is nothing to branch on)."""
        if not self.tiles_for(height, width):
            return None
        return _GuardHead(self), _GuardWhole(self), _GuardTail()


class _GuardHead(torch.nn.Module):
    """The network, its filter and the tiled margin (:meth:`GuardedNetwork.export_parts`)."""

    def __init__(self, guarded: GuardedNetwork) -> None:
        super().__init__()
        self.guarded = guarded

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, ...]:
        guarded = self.guarded
        network_input, filter_input = guarded._network_and_filter(target, captured)
        tiles = guarded.tiles_for(target.shape[-2], target.shape[-1])
        psfs: torch.Tensor = guarded.psfs.contiguous()  # type: ignore[operator]  # a registered buffer
        margin = tiled_guard_choice(target, network_input, filter_input, psfs, tiles, guarded.tile_px)[1]
        return network_input, filter_input, margin, (margin.abs() < GUARD_MARGIN_BAND).any()


class _GuardWhole(torch.nn.Module):
    """The whole frame's margin (:meth:`GuardedNetwork.export_parts`)."""

    def __init__(self, guarded: GuardedNetwork) -> None:
        super().__init__()
        self.guarded = guarded

    def forward(self, target: torch.Tensor, network_input: torch.Tensor, filter_input: torch.Tensor) -> torch.Tensor:
        return guard_choice(target, network_input, filter_input, self.guarded._screens_for(target))[1]


class _GuardTail(torch.nn.Module):
    """``x`` where ``margin >= 0``, else ``E(I)`` (:meth:`GuardedNetwork.export_parts`)."""

    def forward(self, network_input: torch.Tensor, filter_input: torch.Tensor, margin: torch.Tensor) -> torch.Tensor:
        return torch.where((margin < 0).view(-1, 1, 1, 1), filter_input, network_input)


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
