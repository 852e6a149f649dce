"""Multi-rate real-time network: identity at start, bilinear return path, fused pixel shuffle,
any size, TorchScript export, config."""

import warnings

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from edofproj.compensation.export import export_network
from edofproj.compensation.multirate import (
    MultirateCompensationNet,
    add_block_pixels,
    bilinear_block_weights,
    polyphase_taps,
    unshuffle_weight,
)
from edofproj.compensation.registry import build_network
from edofproj.config import Config, ConfigError
from edofproj.errors import EdofprojError
from edofproj.net_config import MultirateConfig

SMALL = [4, 6, 8]


def images(height, width, batch=1, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(batch, 3, height, width, generator=gen), torch.rand(batch, 3, height, width, generator=gen))


def trained_looking(net, seed=0):
    """Randomize every zero-initialized part (head, filter nodes, local filter) so the output is not the identity."""
    torch.manual_seed(seed)
    with torch.no_grad():
        net.head.weight.normal_(0, 0.2)
        net.head.bias.normal_(0, 0.05)
        net.prefilter.gain.normal_(0, 0.1)
        net.linear_gain.weight.normal_(0, 0.1)
        for local, upsampling in zip(net.local_filter, net.correction_to_pixels):
            local.weight.normal_(0, 0.05)
            upsampling.weight.add_(0.05 * torch.randn_like(upsampling.weight))
    return net.eval()


@pytest.mark.parametrize("size", [(600, 800), (37, 53), (1, 1), (5, 130)])
def test_untrained_network_is_the_identity(size):
    net = MultirateCompensationNet(SMALL)
    target, captured = images(*size, batch=2)
    with torch.no_grad():
        out = net(target, captured)
    assert out.shape == target.shape
    torch.testing.assert_close(out, target, rtol=0, atol=2e-6)  # FFT round-off of the identity filter


@pytest.mark.parametrize("block", [2, 3, 4, 5])
def test_bilinear_block_weights_interpolate_a_ramp_exactly(block):
    """Each pixel's 3x3 weights sum to 1, and a linear ramp's block means (the ramp's value at the
    block centres) come back as the ramp itself away from the border."""
    weights = bilinear_block_weights(block)
    torch.testing.assert_close(weights.sum(dim=(-2, -1)), torch.ones(block, block))
    net = MultirateCompensationNet(SMALL, block=block)
    hb, wb = 9, 11
    yy, xx = torch.meshgrid(
        torch.arange(hb * block, dtype=torch.float64), torch.arange(wb * block, dtype=torch.float64), indexing="ij"
    )
    ramp = (0.3 * yy - 0.7 * xx + 2.0).float()[None, None]
    means = F.avg_pool2d(ramp, block)
    with torch.no_grad():
        values = net.correction_to_pixels[1](F.pad(means, (1, 1, 1, 1), mode="replicate"))  # (1, s^2, hb, wb)
    upsampled = F.pixel_shuffle(values, block)
    inner = (..., slice(block, -block), slice(block, -block))
    torch.testing.assert_close(upsampled[inner], ramp[inner], rtol=0, atol=1e-4)


def test_unshuffle_convolution_equals_pixel_unshuffle():
    image = torch.rand(2, 1, 12, 20)
    torch.testing.assert_close(
        F.conv2d(image, unshuffle_weight(4), stride=4), F.pixel_unshuffle(image, 4), rtol=0, atol=0
    )


def test_fused_block_sum_equals_pixel_shuffle():
    """``add_block_pixels`` == image + pixel_shuffle(blocks), in either memory format."""
    s, c = 4, 3
    image = torch.rand(2, c, 12, 20)
    blocks = torch.rand(2, s * s * c, 3, 5)
    reference = image + F.pixel_shuffle(blocks, s)
    torch.testing.assert_close(add_block_pixels(image, blocks, s), reference, rtol=0, atol=0)
    last = torch.channels_last
    torch.testing.assert_close(
        add_block_pixels(image, blocks.contiguous(memory_format=last), s), reference, rtol=0, atol=0
    )


@pytest.mark.parametrize("block, radius", [(4, 4), (4, 1), (3, 3), (2, 2)])
def test_linear_path_started_from_kernels_is_their_full_resolution_convolution(block, radius):
    """``initialize_linear_path`` loads the polyphase taps of one convolution kernel per colour
    into L: the untrained network then equals that convolution of the replicate-padded image,
    border included (the blocks' border is made of replicated pixels), against F.conv2d."""
    torch.manual_seed(block + radius)
    kernels = torch.randn(3, 2 * radius + 1, 2 * radius + 1, dtype=torch.float64)
    net = MultirateCompensationNet(SMALL, block=block).eval()
    net.initialize_linear_path(kernels)
    target, captured = images(6 * block, 9 * block, batch=2)
    with torch.no_grad():
        out = net(target, captured).double()
    r = radius
    reference = F.conv2d(
        F.pad(target.double(), (r, r, r, r), mode="replicate"), kernels.flip(-2, -1)[:, None], groups=3
    )
    torch.testing.assert_close(out, reference, rtol=0, atol=2e-5)
    assert (out - target).abs().max() > 0.1


def test_polyphase_taps_refuse_a_kernel_wider_than_the_blocks_reach():
    assert polyphase_taps(torch.ones(9, 9), 4).shape == (16, 16, 3, 3)
    for kernel in (torch.ones(11, 11), torch.ones(4, 4), torch.ones(3, 5)):
        with pytest.raises(EdofprojError, match="polyphase kernel"):
            polyphase_taps(kernel, 4)
    with pytest.raises(EdofprojError, match="kernels"):
        MultirateCompensationNet(SMALL).initialize_linear_path(torch.ones(2, 3, 3))


def test_linear_gain_scales_the_whole_linear_correction():
    """``(1 + g)`` multiplies ``L U + B D``: a constant gain g = 1 doubles what the linear path adds."""
    net = MultirateCompensationNet(SMALL).eval()
    net.initialize_linear_path(
        torch.tensor([[0.0, -0.25, 0.0], [-0.25, 2.0, -0.25], [0.0, -0.25, 0.0]]).expand(3, 3, 3)
    )
    target, captured = images(24, 32)
    with torch.no_grad():
        before = net(target, captured) - target
        net.linear_gain.bias.fill_(1.0)
        after = net(target, captured) - target
    torch.testing.assert_close(after, 2 * before, rtol=0, atol=1e-5)


@pytest.mark.parametrize("size", [(37, 53), (6, 130)])
def test_any_size_equals_explicit_padding_then_crop(size):
    """The net pads bottom/right to a multiple of the block size (replicate) and crops back."""
    height, width = size
    net = trained_looking(MultirateCompensationNet(SMALL))
    target, captured = images(height, width)
    pad = ((0, 0), (0, 0), (0, -height % 4), (0, -width % 4))
    padded_t = torch.from_numpy(np.pad(target.numpy(), pad, mode="edge"))
    padded_c = torch.from_numpy(np.pad(captured.numpy(), pad, mode="edge"))
    with torch.no_grad():
        out = net(target, captured)
        reference = net(padded_t, padded_c)[..., :height, :width]
    assert (out - target).abs().max() > 1e-2
    torch.testing.assert_close(out, reference, rtol=0, atol=1e-6)


@pytest.mark.parametrize("bound", [0.0, 0.2])
def test_inference_path_equals_the_differentiable_path(bound):
    """Without gradients each colour plane is written straight into the output, and the safe form's
    bounded correction runs in place from a head scaled by 2/b (one blur for the three colours);
    same numbers."""
    net = trained_looking(MultirateCompensationNet(SMALL, correction_bound=bound, correction_highpass_px=8.0))
    with torch.no_grad():
        net.head.weight.mul_(5)  # corrections beyond the bound: tanh saturates
    target, captured = images(37, 53, batch=2)
    with torch.no_grad():
        fast = net(target, captured)
    differentiable = net(target, captured)
    assert differentiable.requires_grad
    torch.testing.assert_close(fast, differentiable.detach(), rtol=0, atol=1e-6)


def test_channels_last_and_batch_give_the_same_output():
    net = trained_looking(MultirateCompensationNet(SMALL))
    target, captured = images(40, 56, batch=2)
    with torch.no_grad():
        reference = net(target, captured)
        single = net(target[1:], captured[1:])
        net_cl = net.to(memory_format=torch.channels_last)
        out = net_cl(
            target.contiguous(memory_format=torch.channels_last), captured.contiguous(memory_format=torch.channels_last)
        )
    torch.testing.assert_close(out, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(single, reference[1:], rtol=1e-5, atol=1e-5)


def test_zero_initialized_network_learns_and_gradients_reach_every_part():
    torch.manual_seed(0)
    net = MultirateCompensationNet(SMALL)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    target, captured = images(32, 32, batch=2)
    losses = []
    for _ in range(60):
        optimizer.zero_grad()
        loss = torch.mean((net(target, captured) - (1.2 * target + 0.1)) ** 2)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < 0.1 * losses[0]
    for name in (
        "local_filter.0.weight",
        "local_filter.2.weight",
        "head.weight",
        "prefilter.gain",
        "correction_to_pixels.1.weight",
        "embed_target.weight",
        "linear_gain.weight",
    ):
        assert dict(net.named_parameters())[name].grad.abs().sum() > 0, name


def test_torchscript_export_matches_pytorch_at_two_sizes(tmp_path):
    net = trained_looking(MultirateCompensationNet(SMALL))
    worst = export_network(net, tmp_path / "net.pt", "torchscript", height=64, width=96)
    assert 0.0 <= worst <= 1e-4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = torch.jit.load(str(tmp_path / "net.pt"))
    target, captured = images(45, 77, seed=3)
    with torch.no_grad():
        torch.testing.assert_close(loaded(target, captured), net(target, captured), rtol=0, atol=1e-5)


@pytest.mark.parametrize("upsampling", ["transpose", "bilinear"])
def test_unet_follows_the_configured_upsampling_and_skips_blocks_at_the_finest_scale(upsampling):
    net = MultirateCompensationNet([4, 6, 8], upsampling=upsampling)
    first = net.up[0] if upsampling == "transpose" else net.up[0][0]
    assert isinstance(first, torch.nn.ConvTranspose2d if upsampling == "transpose" else torch.nn.Upsample)
    assert isinstance(net.encoder[0], torch.nn.Identity)
    convs = [m for m in net.decoder[-1].modules() if isinstance(m, torch.nn.Conv2d)]
    assert [m.kernel_size for m in convs] == [(1, 1)]


def test_config_builds_the_network_and_refuses_bad_values():
    cfg = Config()
    cfg.net = MultirateConfig(widths=[8, 12, 16], block_px=4, filter_bins=24)
    cfg.net.validate()
    net = build_network(cfg.net)
    assert isinstance(net, MultirateCompensationNet)
    assert net.block == 4 and net.widths == [8, 12, 16] and net.prefilter.gain.shape == (3, 24)
    with pytest.raises(ConfigError, match="block_px=1 must be an integer >= 2"):
        MultirateConfig(block_px=1, filter_bins=24).validate()
    with pytest.raises(ConfigError, match="filter_bins=0 must be an integer >= 2"):
        MultirateConfig(block_px=4, filter_bins=0).validate()
    for bad in (-0.1, float("nan")):
        with pytest.raises(ConfigError, match="init_nsr"):
            MultirateConfig(block_px=4, filter_bins=24, init_nsr=bad).validate()
    with pytest.raises(EdofprojError, match="block=1"):
        MultirateCompensationNet(SMALL, block=1)
    with pytest.raises(EdofprojError, match="same shape"):
        MultirateCompensationNet(SMALL)(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 9))


def assert_network_is_the_ensemble_filter(net, psfs, nsr: float) -> None:
    """The network (non-linear part untrained, 4x4 blocks) equals the full-resolution convolution with
    the depth-ensemble Wiener kernel of ``psfs`` cut to radius 4, replicate border."""
    from edofproj.compensation.wiener import depth_ensemble_wiener_kernel

    kernels = torch.from_numpy(depth_ensemble_wiener_kernel(psfs, nsr, radius=4))
    target, captured = images(24, 32)
    with torch.no_grad():
        out = net(target, captured).double()
    reference = F.conv2d(
        F.pad(target.double(), (4, 4, 4, 4), mode="replicate"), kernels.flip(-2, -1)[:, None], groups=3
    )
    torch.testing.assert_close(out, reference, rtol=0, atol=2e-5)


def test_a_fixed_doe_run_starts_from_the_depth_ensemble_wiener_filter():
    """``start_from_wiener`` loads the cut ensemble Wiener kernel of a PSF table into L (the
    untrained network then equals that convolution), and leaves the network alone for a DOE
    being trained (no table), for ``init_nsr = 0`` and for networks without a linear path."""
    from edofproj.compensation.unet import CompensationUNet
    from edofproj.training.psf_table import DepthPSFTable
    from edofproj.training.trainer import start_from_wiener

    psf = torch.zeros(3, 3, 9, 9)
    for i, sigma in enumerate((0.6, 0.9, 1.2)):  # blur growing with depth, like defocus
        r2 = (torch.arange(9.0) - 4)[:, None] ** 2 + (torch.arange(9.0) - 4)[None] ** 2
        psf[i] = torch.exp(-r2 / (2 * sigma**2)) / torch.exp(-r2 / (2 * sigma**2)).sum()
    table = DepthPSFTable(psf, 1 / np.linspace(1 / 0.8, 1 / 0.3, 3))
    cfg = Config()
    cfg.net = MultirateConfig(widths=SMALL, block_px=4, filter_bins=8, init_nsr=0.01)
    net = build_network(cfg.net).eval()
    start_from_wiener(cfg, net, table)
    assert_network_is_the_ensemble_filter(net, psf.numpy(), 0.01)

    for untouched_cfg, source in ((cfg, torch.nn.Identity()), (Config(), table)):
        if source is table:
            untouched_cfg.net = MultirateConfig(widths=SMALL, block_px=4, filter_bins=8, init_nsr=0.0)
        fresh = build_network(untouched_cfg.net)
        start_from_wiener(untouched_cfg, fresh, source)
        assert all(local.weight.abs().max() == 0 for local in fresh.local_filter)
    unet = CompensationUNet([4, 8])
    before = [p.clone() for p in unet.parameters()]
    start_from_wiener(cfg, unet, table)
    assert all(torch.equal(a, b) for a, b in zip(before, unet.parameters()))


# ----------------------------------------------------------------------------- the safe form


def linear_path_only(net: MultirateCompensationNet, target, captured) -> torch.Tensor:
    """``I + S(L U + B D)``: the network with its non-linear part (head and depth gain) set to zero."""
    head_w, head_b = net.head.weight.clone(), net.head.bias.clone()
    gain_w, gain_b = net.linear_gain.weight.clone(), net.linear_gain.bias.clone()
    with torch.no_grad():
        for p in (net.head.weight, net.head.bias, net.linear_gain.weight, net.linear_gain.bias):
            p.zero_()
        out = net(target, captured)
        net.head.weight.copy_(head_w), net.head.bias.copy_(head_b)
        net.linear_gain.weight.copy_(gain_w), net.linear_gain.bias.copy_(gain_b)
    return out


@pytest.mark.parametrize("highpass_px", [0.0, 8.0])
def test_safe_form_stays_within_its_bound_of_its_own_linear_path(highpass_px):
    """Whatever the weights (here large random ones that move the output by far more than the
    bound), ``|x - (I + S(L U + B D))| <= b`` at every pixel, and the bound is reached closely."""
    bound = 0.1
    net = trained_looking(MultirateCompensationNet(SMALL, correction_bound=bound, correction_highpass_px=highpass_px))
    with torch.no_grad():
        net.head.weight.mul_(20.0)
        net.head.bias.mul_(20.0)
    target, captured = images(48, 64, batch=2)
    with torch.no_grad():
        out = net(target, captured)
    deviation = (out - linear_path_only(net, target, captured)).abs()
    assert float(deviation.max()) <= bound + 1e-6
    assert float(deviation.max()) > 0.5 * bound  # the non-linear part is active, not switched off


def test_safe_form_with_highpass_keeps_the_linear_level_over_a_flat_area():
    """Over a flat target (and capture) the high-passed correction has almost no level of its own:
    with a head that adds a large constant to every pixel, each block's mean stays within 1 % of
    the bound of the linear path's away from the border (the U-Net's own border effects leave
    ~1e-4), where the bound alone would let it move by the whole bound; what remains is a zero-mean
    pattern inside the blocks, bounded by b."""
    target = torch.full((1, 3, 96, 96), 0.4)
    level = {}
    for highpass_px in (0.0, 4.0):
        net = trained_looking(MultirateCompensationNet(SMALL, correction_bound=0.2, correction_highpass_px=highpass_px))
        with torch.no_grad():
            net.head.bias.fill_(5.0)  # an unbounded network would add 5 to every pixel
            out = net(target, target.clone())
        deviation = out - linear_path_only(net, target, target.clone())
        assert float(deviation.abs().max()) <= 0.2 + 1e-6
        level[highpass_px] = float(F.avg_pool2d(deviation, 4)[..., 4:-4, 4:-4].abs().max())  # 16 px from the border
    assert level[4.0] < 0.002 and level[0.0] > 0.1


def test_safe_form_untrained_is_the_identity_and_unbounded_form_is_unchanged():
    """An untrained safe network is the identity (its correction is ``HP(0) = 0``); the default
    (``correction_bound = 0``) is the unbounded form, output for output."""
    target, captured = images(37, 53, batch=2)
    safe = MultirateCompensationNet(SMALL, correction_bound=0.2, correction_highpass_px=8.0).eval()
    with torch.no_grad():
        torch.testing.assert_close(safe(target, captured), target, rtol=0, atol=2e-6)
    torch.manual_seed(0)
    plain = trained_looking(MultirateCompensationNet(SMALL))
    torch.manual_seed(0)
    default = trained_looking(MultirateCompensationNet(SMALL, correction_bound=0.0, correction_highpass_px=8.0))
    with torch.no_grad():
        torch.testing.assert_close(default(target, captured), plain(target, captured), rtol=0, atol=0)


def test_safe_form_trains_and_its_config_keys_build_it():
    cfg = Config()
    cfg.net = MultirateConfig(widths=[4, 8], correction_bound=0.15, correction_highpass_px=8.0)
    net = build_network(cfg.net)
    assert net.correction_bound == 0.15 and net.correction_highpass_blocks == 2.0
    trained_looking(net).train()
    target, captured = images(32, 32)
    net(target, captured).square().mean().backward()
    assert float(net.head.weight.grad.abs().max()) > 0 and float(net.linear_gain.weight.grad.abs().max()) > 0
    with pytest.raises(EdofprojError, match="correction_bound"):
        MultirateCompensationNet(SMALL, correction_bound=-0.1)


def test_a_fixed_linear_path_is_frozen_at_the_wiener_start_and_the_rest_trains():
    """``net.linear_path: fixed``: after ``start_from_wiener`` the linear path (L, B, the block-mean
    filter) no longer takes gradients and still holds the Wiener start; the non-linear part does."""
    from edofproj.training.psf_table import DepthPSFTable
    from edofproj.training.trainer import start_from_wiener

    r2 = (torch.arange(9.0) - 4)[:, None] ** 2 + (torch.arange(9.0) - 4)[None] ** 2
    psf = torch.stack([torch.exp(-r2 / (2 * s**2)) / torch.exp(-r2 / (2 * s**2)).sum() for s in (0.6, 0.9, 1.2)])
    table = DepthPSFTable(psf[:, None].expand(3, 3, 9, 9).contiguous(), 1 / np.linspace(1 / 0.8, 1 / 0.3, 3))
    cfg = Config()
    cfg.net = MultirateConfig(widths=SMALL, filter_bins=8, linear_path="fixed", correction_bound=0.2)
    net = build_network(cfg.net)
    start_from_wiener(cfg, net, table)
    linear = [*net.local_filter.parameters(), *net.correction_to_pixels.parameters(), *net.prefilter.parameters()]
    assert linear and not any(p.requires_grad for p in linear)
    assert max(float(local.weight.abs().max()) for local in net.local_filter) > 0  # the Wiener start
    trainable = [p for p in net.parameters() if p.requires_grad]
    assert net.head.weight.requires_grad and net.linear_gain.weight.requires_grad and trainable
    with pytest.raises(ConfigError, match="init_nsr"):
        MultirateConfig(linear_path="fixed", init_nsr=0.0).check_together()


def test_a_fixed_linear_path_follows_a_doe_being_trained():
    """For a DOE being trained (PSFs simulated at each call, no table) the fixed linear path is frozen
    and ``refresh_linear_base`` sets it to the depth-ensemble Wiener filter of the PSFs the source
    gives *now*: the untrained network then equals that filter's full-resolution convolution, and
    it changes when the PSFs change."""
    from edofproj.compensation.linear_base import ensemble_depths_m
    from edofproj.training.linear_filter import refresh_linear_base
    from edofproj.training.trainer import start_from_wiener

    r2 = (torch.arange(9.0) - 4)[:, None] ** 2 + (torch.arange(9.0) - 4)[None] ** 2

    class Blur(torch.nn.Module):  # a "DOE being trained": PSFs of any depth, growing with 1/z
        def __init__(self, scale):
            super().__init__()
            self.scale = scale

        def forward(self, depths_m):
            sigma = torch.as_tensor(self.scale / np.asarray(depths_m), dtype=torch.float32)
            psf = torch.exp(-r2 / (2 * sigma[:, None, None] ** 2))
            return (psf / psf.sum(dim=(-2, -1), keepdim=True))[:, None].expand(-1, 3, 9, 9)

    cfg = Config()
    cfg.evaluation.score_range_mm = [300.0, 800.0]
    cfg.net = MultirateConfig(widths=SMALL, filter_bins=8, linear_path="fixed", correction_bound=0.2)
    net = build_network(cfg.net).eval()
    source = Blur(0.3)
    start_from_wiener(cfg, net, source)
    assert not any(p.requires_grad for p in net.local_filter.parameters())
    assert all(float(local.weight.abs().max()) == 0 for local in net.local_filter)  # set by the refresh
    refresh_linear_base(cfg, net, source)
    assert_network_is_the_ensemble_filter(net, source(ensemble_depths_m(0.3, 0.8)).numpy(), cfg.net.init_nsr)
    before = net.local_filter[0].weight.clone()
    source.scale = 0.4  # the DOE moved: the path follows at the next refresh
    refresh_linear_base(cfg, net, source)
    assert float((net.local_filter[0].weight - before).abs().max()) > 1e-3
