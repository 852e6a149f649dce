"""The display guard (:mod:`edofproj.methods.guard`): a safe network's input is sent only where its
predicted display scores at least its linear filter's, so the guarded network is never behind the
filter in mean SSIM over the guard's depths, whatever the weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.unet import CompensationUNet
from edofproj.imaging.convolution import fast_fft_length, fft_shape
from edofproj.imaging.projection import project
from edofproj.methods.guard import (
    DisplayGuard,
    GuardedNetwork,
    GuardedNetworkCompensation,
    guard_depths_m,
    guard_tiles,
    predicted_ssim,
)
from edofproj.metrics import gaussian_window, ssim, ssim_map
from synthetic_psfs import gaussian_psfs

PSFS = gaussian_psfs([0.8, 2.0, 3.5])


def safe_net(scramble: float = 0.0) -> CompensationUNet:
    torch.manual_seed(0)
    net = CompensationUNet([4, 8, 8], linear_radius=10, correction_bound=0.2, correction_highpass_px=4.0)
    net.linear_base.set_from_psfs(gaussian_psfs([0.8, 1.5, 2.5, 3.5]), 0.01)
    if scramble:
        generator = torch.Generator().manual_seed(1)
        with torch.no_grad():
            for parameter in net.parameters():
                parameter.copy_(scramble * torch.randn(parameter.shape, generator=generator))
    return net.eval()


def images() -> torch.Tensor:
    generator = torch.Generator().manual_seed(2)
    smooth = torch.nn.functional.avg_pool2d(torch.rand(3, 3, 72, 72, generator=generator), 9, 1)
    return smooth.clamp(0, 1)


def test_guard_depths_are_the_ends_and_the_middle_in_inverse_depth():
    depths = guard_depths_m(0.3, 0.8)
    np.testing.assert_allclose(depths, [0.3, 2 / (1 / 0.3 + 1 / 0.8), 0.8])


def test_predicted_ssim_is_the_mean_of_the_ssims_of_the_displays():
    target = images()
    expected = torch.stack([ssim(project(target, psf[None]), target) for psf in PSFS]).mean(0)
    torch.testing.assert_close(predicted_ssim(target, target, PSFS), expected)


@pytest.mark.parametrize("scramble", [0.0, 0.3, 1.0])
def test_the_guarded_display_never_scores_below_the_filters(scramble):
    net = safe_net(scramble)
    compensate = GuardedNetworkCompensation(net, PSFS)
    target = images()
    captured = project(target, PSFS[1:2])
    with torch.no_grad():
        shown = compensate(target, captured, PSFS[1:2])
        raw = net(target, captured)
        base = net.linear_base(target)
    s_shown, s_raw, s_base = (predicted_ssim(v, target, PSFS) for v in (shown, raw, base))
    assert torch.all(s_shown >= s_base)
    torch.testing.assert_close(s_shown, torch.maximum(s_raw, s_base))
    for i, filter_sent in enumerate(compensate.guard.chose_filter):
        torch.testing.assert_close(shown[i], base[i] if filter_sent else raw[i])
    if scramble == 0.0:  # untrained: the network is its filter, a tie, and the network's input is sent
        assert not compensate.guard.chose_filter.any()
    if scramble == 1.0:  # large random weights spoil every image: the filter is sent
        assert compensate.guard.chose_filter.all()


def test_the_guard_sends_the_better_of_two_known_inputs():
    target = images()
    guard = DisplayGuard(PSFS)
    black = torch.zeros_like(target)
    assert torch.equal(guard(target, target, black), target) and not guard.chose_filter.any()
    assert torch.equal(guard(target, black, target), target) and guard.chose_filter.all()
    assert (guard.filter_count, guard.calls) == (3, 6)


def test_the_guard_refuses_a_network_without_a_linear_base():
    with pytest.raises(ValueError, match="linear base"):
        GuardedNetworkCompensation(CompensationUNet([4, 8]), PSFS)


def textured(height: int, width: int, seed: int = 3) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.nn.functional.avg_pool2d(torch.rand(2, 3, height + 4, width + 4, generator=generator), 5, 1)


def test_the_tiles_lie_in_the_ssim_map_apart_and_within_their_budget():
    """At 600x800 with a 33-px PSF: tiles inside the (H - 2r) x (W - 2r) map, none overlapping, their
    FFT grids within ``work_fraction`` of the whole frame's; a small frame is scored whole."""
    radius = gaussian_window().numel() // 2
    for fraction in (0.06, 0.15, 0.3):
        tiles = guard_tiles(600, 800, 33, 32, fraction)
        assert len(tiles) >= 1
        occupied = torch.zeros(600 - 2 * radius, 800 - 2 * radius, dtype=torch.int32)
        for top, left in tiles:
            assert top >= 0 and left >= 0 and top + 32 <= occupied.shape[0] and left + 32 <= occupied.shape[1]
            occupied[top : top + 32, left : left + 32] += 1
        assert int(occupied.max()) == 1
        tile_grid = fast_fft_length(32 + 2 * radius + 2 * 16)
        whole = fft_shape((600, 800), (33, 33))
        assert len(tiles) * tile_grid**2 <= fraction * whole[0] * whole[1]
    assert guard_tiles(72, 72, 15) == []


@pytest.mark.parametrize("scramble", [0.3, 1.0])
def test_the_tiled_margin_is_the_whole_frames_ssim_map_averaged_over_the_tiles(scramble):
    """Computed independently: each depth's flat-screen display of the whole frame
    (:func:`project`), its local SSIM map (:func:`ssim_map`), averaged over the tiles' pixels and the
    depths; the tiled rule sends the input with the larger estimate."""
    net = safe_net(scramble)
    guarded = GuardedNetwork(net, PSFS).eval()
    guarded.work_fraction = 0.5
    target = textured(150, 210)
    captured = project(target, PSFS[1:2])
    tiles = guarded.tiles_for(150, 210)
    assert len(tiles) >= 2
    radius, side = gaussian_window().numel() // 2, guarded.tile_px

    def estimate(v: torch.Tensor) -> torch.Tensor:
        per_depth = []
        for psf in PSFS:
            local = ssim_map(project(v, psf[None]), target)
            pixels = [local[:, radius + t : radius + t + side, radius + c : radius + c + side] for t, c in tiles]
            per_depth.append(torch.stack(pixels).mean(dim=(0, 2, 3)))
        return torch.stack(per_depth).mean(0)

    with torch.no_grad():
        shown, margin = guarded.decide(target, captured)
        raw, base = net(target, captured), net.linear_base(target)
    torch.testing.assert_close(margin, estimate(raw) - estimate(base), atol=1e-6, rtol=0)
    for i in range(len(target)):
        torch.testing.assert_close(shown[i], base[i] if margin[i] < 0 else raw[i], atol=0, rtol=0)


def test_the_guard_keeps_the_networks_linear_filter_output():
    """The network computes ``E(I)`` for ``x = E(I) + c``; the guard uses that output instead of
    filtering the target a second time (one call of the filter per frame)."""
    net = safe_net(0.3)
    guarded = GuardedNetwork(net, PSFS).eval()
    calls = []
    net.linear_base.register_forward_hook(lambda module, args, output: calls.append(output))
    target = images()
    with torch.no_grad():
        shown, margin = guarded.decide(target, project(target, PSFS[1:2]))
    assert len(calls) == 1
    raw = net(target, project(target, PSFS[1:2]))
    for i in range(len(target)):
        torch.testing.assert_close(shown[i], calls[0][i] if margin[i] < 0 else raw[i], atol=0, rtol=0)


def test_a_tiled_margin_near_a_tie_is_decided_on_the_whole_frame(monkeypatch):
    """Within the band the whole frame's margin (:func:`predicted_ssim`) decides; outside it the tiles'."""
    import edofproj.methods.guard as guard_module

    net = safe_net(0.3)
    guarded = GuardedNetwork(net, PSFS).eval()
    guarded.work_fraction = 0.5
    target = textured(150, 210)
    captured = project(target, PSFS[1:2])
    with torch.no_grad():
        raw, base = net(target, captured), net.linear_base(target)
        whole = predicted_ssim(raw, target, PSFS) - predicted_ssim(base, target, PSFS)
        monkeypatch.setattr(guard_module, "GUARD_MARGIN_BAND", 0.0)
        tiled = guarded.decide(target, captured)[1]
        monkeypatch.setattr(guard_module, "GUARD_MARGIN_BAND", float(tiled.abs().max()) * 2)
        shown, margin = guarded.decide(target, captured)
    assert not torch.allclose(tiled, whole, atol=1e-6, rtol=0)
    torch.testing.assert_close(margin, whole, atol=1e-6, rtol=0)
    for i in range(len(target)):
        torch.testing.assert_close(shown[i], base[i] if whole[i] < 0 else raw[i], atol=0, rtol=0)
