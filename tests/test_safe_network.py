"""The safe compensation network (``net.linear_base: ensemble``): its construction, checked against
the evaluation's own linear baseline and against closed forms.

* untrained, it *is* the depth-ensemble linear filter ``doe+ensemble`` (the evaluation's
  independent implementation), bit for bit up to float rounding;
* for any weights, ``|x - E(I)| <= b`` and, at any depth, ``|A(x) - A(E(I))| <= b`` (the projection
  is non-expansive in the maximum norm);
* a uniform colour with one primary at 5 % is sent at 5 % +- 0.5 % whatever the weights (the
  correction carries no local mean) and comes back so on the screen while the correction stays
  within the level; without the high-pass a uniform correction shifts it;
* the correction ignores a constant added to the U-Net's residual, so a residual whose mean has
  drifted far beyond the bound (what killed a 10,000-step reference run when the bound came before
  the high-pass) still passes gradients and still trains.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.linear_base import LinearBase, bounded_correction, ensemble_depths_m
from edofproj.compensation.registry import build_network
from edofproj.compensation.unet import CompensationUNet
from edofproj.config import ConfigError, load_config
from edofproj.imaging.projection import project
from edofproj.methods.compensators import EnsembleWienerCompensation
from synthetic_psfs import gaussian_psfs

RADIUS = 12
NSR = 0.01


def safe_unet(bound: float = 0.2, highpass_px: float = 4.0) -> CompensationUNet:
    torch.manual_seed(0)
    net = CompensationUNet([4, 8, 8], linear_radius=RADIUS, correction_bound=bound, correction_highpass_px=highpass_px)
    net.linear_base.set_from_psfs(gaussian_psfs([0.8, 1.5, 2.5, 3.5]), NSR)
    return net.eval()


def scramble_head(net: CompensationUNet, scale: float = 1.0) -> None:
    """Large random weights in every layer: the correction is far from zero and varies across the image."""
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for parameter in net.parameters():
            parameter.copy_(scale * torch.randn(parameter.shape, generator=generator))


def test_untrained_safe_network_is_the_evaluations_depth_ensemble_filter():
    psfs = gaussian_psfs([0.8, 1.5, 2.5, 3.5])
    net = safe_unet()
    baseline = EnsembleWienerCompensation(psfs, NSR, RADIUS)
    image = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        x = net(image, project(image, psfs[:1]))
    torch.testing.assert_close(x, baseline(image, image, psfs[:1]), atol=1e-6, rtol=0)


@pytest.mark.parametrize("highpass_px", [0.0, 4.0])
def test_correction_is_bounded_and_so_is_the_display_difference_at_every_depth(highpass_px):
    bound = 0.1
    net = safe_unet(bound, highpass_px)
    scramble_head(net)
    image = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(3))
    psfs = gaussian_psfs([0.5, 2.0, 4.0])
    with torch.no_grad():
        base = net.linear_base(image)
        for psf in psfs:
            x = net(image, project(image, psf[None]))
            assert (x - base).abs().max() <= bound + 1e-6
            assert (x - base).abs().max() > 0.2 * bound  # the scrambled correction is far from zero
            difference = project(x, psf[None]) - project(base, psf[None])
            assert difference.abs().max() <= bound + 1e-6


def test_bounded_correction_closed_form_without_highpass():
    r = torch.linspace(-3, 3, 61).view(1, 1, 1, 61).expand(1, 3, 4, 61)
    torch.testing.assert_close(bounded_correction(r, 0.2, 0.0), 0.2 * torch.tanh(r / 0.2))


def test_correction_ignores_a_drifted_residual_mean():
    """``HP_s`` before the bound: ``c(r + m) = c(r)`` for any constant ``m`` (to float rounding at ``|m|``)."""
    r = 0.3 * torch.randn(2, 3, 40, 48, generator=torch.Generator().manual_seed(5))
    reference = bounded_correction(r, 0.2, 4.0)
    for drift in (-100.0, 3.0, 100.0):
        torch.testing.assert_close(bounded_correction(r + drift, 0.2, 4.0), reference, atol=1e-4, rtol=0)
    assert reference.abs().max() > 0.05  # not trivially zero


def test_a_drifted_residual_still_trains():
    """A residual 1000 beyond the bound (tanh of the old form saturated at every pixel: zero gradient)
    still gets a gradient, and a few Adam steps on a deblurring loss move the display towards the target."""
    net = safe_unet(0.2, 4.0).train()
    with torch.no_grad():
        net.head.bias.fill_(-1000.0)
    target = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(6))
    psf = gaussian_psfs([2.5])
    captured = project(target, psf)

    def loss() -> torch.Tensor:
        return ((project(net(target, captured), psf) - target) ** 2).mean()

    start = float(loss().detach())
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(20):
        optimizer.zero_grad()
        value = loss()
        value.backward()
        assert net.head.weight.grad is not None and float(net.head.weight.grad.abs().max()) > 1e-6
        optimizer.step()
    assert float(loss().detach()) < start - 1e-3


def test_a_network_scored_in_inference_mode_still_trains_afterwards():
    """The blur matrices of the high-pass are cached: a frame compensated under ``torch.inference_mode`` first
    (``evaluate``, ``compensate``) must not leave inference tensors that refuse a later training step of the
    same size in the same process."""
    net = safe_unet(0.2, 3.7).train()  # a sigma no other test uses: the cache starts empty for it
    target = torch.rand(1, 3, 40, 56, generator=torch.Generator().manual_seed(8))
    with torch.inference_mode():
        net(target, target)
    loss = (net(target, target) - target).square().mean()
    loss.backward()
    assert net.head.weight.grad is not None and torch.isfinite(net.head.weight.grad).all()


def test_correction_is_float32_under_bfloat16_autocast():
    r = 0.3 * torch.randn(1, 3, 32, 32, generator=torch.Generator().manual_seed(7))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        c = bounded_correction(r.bfloat16(), 0.2, 4.0)
    assert c.dtype == torch.float32
    torch.testing.assert_close(c, bounded_correction(r.bfloat16().float(), 0.2, 4.0))


def uniform_colour(level_blue: float = 0.05, size: int = 64) -> torch.Tensor:
    colour = torch.tensor([0.8, 0.7, level_blue]).view(1, 3, 1, 1)
    return colour.expand(1, 3, size, size).contiguous()


@pytest.mark.parametrize("scale", [0.1, 0.3, 1.0])
def test_a_nearly_empty_primary_keeps_its_level_whatever_the_weights(scale):
    """5 % blue stays at 5 % +- 0.5 % in the projector input for any weights (the correction has no
    local mean; the filter's DC gain is 1 / (1 + NSR)), and on the screen while the correction's
    swings stay within the level (larger negative swings are clipped by the projector, module
    docstring of :mod:`edofproj.compensation.linear_base`)."""
    net = safe_unet()
    scramble_head(net, scale)
    target = uniform_colour()
    psf = gaussian_psfs([2.0])
    with torch.no_grad():
        x = net(target, project(target, psf))
        display = project(x, psf)
    base = net.linear_base(target)[0, 2, 16:-16, 16:-16]
    assert float(base.mean()) == pytest.approx(0.05 / (1 + NSR), abs=1e-4)
    assert abs(float(x[0, 2, 16:-16, 16:-16].mean()) - 0.05) < 0.005
    if float((x - net.linear_base(target))[0, 2].min()) > -0.05:  # no clipped swing
        assert abs(float(display[0, 2, 16:-16, 16:-16].mean()) - 0.05) < 0.005


def test_without_the_highpass_a_uniform_correction_would_shift_the_level():
    """The check above can fail: a bias of -0.1 on blue empties the channel unless the correction is mean-free."""
    target, psf = uniform_colour(), gaussian_psfs([2.0])
    levels = {}
    for highpass_px in (0.0, 4.0):
        net = safe_unet(0.2, highpass_px)
        with torch.no_grad():
            net.head.bias[2] = -0.1
            levels[highpass_px] = float(project(net(target, target), psf)[0, 2, 16:-16, 16:-16].mean())
    assert levels[0.0] < 0.01
    assert abs(levels[4.0] - 0.05) < 0.005


def test_linear_base_keeps_its_kernel_in_the_state_dict():
    net = safe_unet()
    state = net.state_dict()
    fresh = CompensationUNet([4, 8, 8], linear_radius=RADIUS)
    assert torch.equal(fresh.linear_base.kernel[:, RADIUS, RADIUS], torch.ones(3))  # starts as the identity
    fresh.load_state_dict(state)
    torch.testing.assert_close(fresh.linear_base.kernel, net.linear_base.kernel)


def test_ensemble_depths_are_uniform_in_inverse_depth():
    depths = ensemble_depths_m(0.3, 0.8, 5)
    assert depths[0] == pytest.approx(0.3) and depths[-1] == pytest.approx(0.8)
    np.testing.assert_allclose(np.diff(1 / depths), (1 / 0.8 - 1 / 0.3) / 4)


def test_config_builds_the_safe_network_and_rejects_it_with_a_prefilter():
    cfg = load_config("cpu")
    net = build_network(cfg.net)
    assert isinstance(net.linear_base, LinearBase) and net.linear_base.radius == cfg.psf.window
    with pytest.raises(ConfigError, match="linear_base"):
        load_config("cpu", ["net.prefilter_bins=48"])
