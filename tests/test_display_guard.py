"""The display guard (:mod:`edofproj.methods.guard`): a safe network's input is sent only where its
predicted display scores at least its linear filter's, so the guarded network is never behind the
filter in mean SSIM over the guard's depths, whatever the weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.unet import CompensationUNet
from edofproj.imaging.projection import project
from edofproj.methods.guard import DisplayGuard, GuardedNetworkCompensation, guard_depths_m, predicted_ssim
from edofproj.metrics import ssim
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
