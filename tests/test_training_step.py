"""The joint training step: sampling, differentiable image formation, PSF tables, camera, schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.registry import build_network
from edofproj.config import Config, apply_overrides
from edofproj.doe import build_run_doe
from edofproj.errors import EdofprojError
from edofproj.imaging.projection import project
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.training.camera import camera_capture, quantize_8bit_ste
from edofproj.training.end_to_end import EndToEndProjector, SimulatedPSF
from edofproj.training.losses import build_loss
from edofproj.training.psf_table import DepthPSFTable
from edofproj.training.sampling import BatchShard, sample_depths_m, sample_images, sample_noise
from edofproj.training.trainer import _clip, exponential_decay, loss_terms
from tiny_configs import TINY_TRAINING

TINY = TINY_TRAINING + ["train.batch_size=4"]


def tiny_config(*extra: str) -> Config:
    return apply_overrides(Config(), TINY + list(extra))


class _ConstantSource:
    """A training source whose crop is the generator's first uniform draw everywhere."""

    def sample(self, batch_size, crop, generator):
        return torch.rand(batch_size, 1, 1, 1, generator=generator).expand(batch_size, 3, crop, crop).clone()


# ----------------------------------------------------------------------------- sampling


def test_rank_shards_together_draw_the_single_process_batch():
    full = BatchShard.for_rank(4, 0, 1)
    halves = [BatchShard.for_rank(4, r, 2) for r in range(2)]
    depths = sample_depths_m(7, 3, full, 0.3, 0.8)
    split = np.concatenate([sample_depths_m(7, 3, h, 0.3, 0.8) for h in halves])
    assert np.array_equal(depths, split)
    source = _ConstantSource()
    images = sample_images(source, 7, 3, full, 8)
    assert torch.equal(images, torch.cat([sample_images(source, 7, 3, h, 8) for h in halves]))
    noise = sample_noise(7, 3, full, (3, 8, 8))
    assert torch.equal(noise, torch.cat([sample_noise(7, 3, h, (3, 8, 8)) for h in halves]))
    # other steps and seeds draw other depths; all inside the range
    assert not np.array_equal(depths, sample_depths_m(7, 4, full, 0.3, 0.8))
    assert not np.array_equal(depths, sample_depths_m(8, 3, full, 0.3, 0.8))
    assert np.all((depths >= 0.3) & (depths <= 0.8))


def test_defocus_spacing_is_uniform_in_inverse_depth():
    shard = BatchShard.for_rank(4, 0, 1)
    draws = np.concatenate([sample_depths_m(0, t, shard, 0.3, 0.8, "stratified", "defocus") for t in range(1, 501)])
    assert np.all((draws >= 0.3) & (draws <= 0.8))
    # 1/z uniform on [1/0.8, 1/0.3]: the median is at 1/z = the mean of the ends (436.4 mm), the
    # quartiles at a quarter and three quarters of the way; 2000 draws: rank error ~ 1 %.
    inverse_quantiles = 1 / 0.3 + np.array([0.25, 0.5, 0.75]) * (1 / 0.8 - 1 / 0.3)
    np.testing.assert_allclose(np.quantile(1 / draws, [0.75, 0.5, 0.25]), inverse_quantiles, rtol=0.01)
    assert abs(np.median(draws) - 0.4364) < 0.005
    # stratified: sample i of every batch lies in the i-th quarter of the defocus range
    per_index = draws.reshape(-1, 4)
    edges = 1 / (1 / 0.3 + np.linspace(0, 1, 5) * (1 / 0.8 - 1 / 0.3))
    for i in range(4):
        assert np.all((per_index[:, i] >= edges[i] - 1e-12) & (per_index[:, i] <= edges[i + 1] + 1e-12))


def test_stratified_depths_put_one_sample_in_each_subrange():
    shard = BatchShard.for_rank(5, 0, 1)
    for step in range(1, 6):
        depths = sample_depths_m(0, step, shard, 0.3, 0.8, mode="stratified")
        bins = np.floor((depths - 0.3) / 0.1).astype(int)
        assert sorted(bins.tolist()) == [0, 1, 2, 3, 4]


def test_batch_must_divide_among_processes():
    with pytest.raises(EdofprojError, match="divisible"):
        BatchShard.for_rank(3, 0, 2)


# ----------------------------------------------------------------------------- image formation


@pytest.fixture(scope="module")
def tiny():
    cfg = tiny_config()
    torch.manual_seed(0)
    doe = build_run_doe(cfg)
    with torch.no_grad():  # a non-trivial DOE: random last layer
        doe.mlp[-1].weight.normal_(0, 1.0)
    sim = simulator_from_config(cfg)
    return cfg, doe, sim


def test_each_sample_is_rendered_with_the_psf_of_its_own_depth(tiny):
    cfg, doe, sim = tiny
    net = build_network(cfg.net)  # untrained: the identity
    model = EndToEndProjector(SimulatedPSF(doe, sim), net)
    images = torch.rand(2, 3, 24, 24, generator=torch.Generator().manual_seed(1))
    depths = np.array([0.35, 0.8])
    with torch.no_grad():
        out = model(images, depths)
        for i, z in enumerate(depths):
            psf = sim(doe, [z]).float()
            expected = project(images[i : i + 1], psf)
            torch.testing.assert_close(out.captured[i : i + 1], expected, rtol=0, atol=1e-6)
            torch.testing.assert_close(
                out.projected[i : i + 1], project(out.compensated[i : i + 1].clamp(0, 1), psf), rtol=0, atol=1e-6
            )
        swapped = model(images, depths[::-1].copy())
    assert (swapped.captured - out.captured).abs().max() > 1e-3  # the depth matters


def test_projector_emits_only_light_in_unit_range(tiny):
    cfg, doe, sim = tiny

    class Overdrive(torch.nn.Module):
        def forward(self, target, captured):
            return 3 * target - 1  # far outside [0, 1]

    model = EndToEndProjector(SimulatedPSF(doe, sim), Overdrive())
    images = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        out = model(images, [0.5])
        psf = sim(doe, [0.5]).float()
    torch.testing.assert_close(out.projected, project((3 * images - 1).clamp(0, 1), psf), rtol=0, atol=1e-6)
    assert float(out.projected.max()) <= 1.0 + 1e-5


def test_loss_gradient_reaches_the_doe_and_the_net(tiny):
    cfg, doe, sim = tiny
    net = build_network(cfg.net)
    model = EndToEndProjector(SimulatedPSF(doe, sim), net)
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(3))
    out = model(images, [0.4, 0.7])
    loss, mse, perceptual = loss_terms(build_loss(cfg.loss), cfg, out.projected, images)
    loss.backward()
    doe_grads = [p.grad for p in doe.parameters() if p.grad is not None]
    assert doe_grads and all(torch.isfinite(g).all() for g in doe_grads)
    assert max(float(g.abs().max()) for g in doe_grads) > 0
    assert float(net.head.weight.grad.abs().max()) > 0
    assert float(mse) > 0 and float(perceptual) > 0
    torch.testing.assert_close(loss.detach(), cfg.loss.alpha * mse + cfg.loss.beta * perceptual)
    doe.zero_grad()


# ----------------------------------------------------------------------------- fixed DOEs


def test_psf_table_is_exact_on_its_grid_and_converges_between(tiny):
    cfg, doe, sim = tiny
    coarse = DepthPSFTable.simulate(sim, doe, 0.35, 0.8, 5)
    fine = DepthPSFTable.simulate(sim, doe, 0.35, 0.8, 33)
    with torch.no_grad():
        torch.testing.assert_close(coarse(coarse.depths_m), sim(doe, coarse.depths_m).float(), rtol=0, atol=1e-7)
        between = np.array([0.37, 0.45, 0.61, 0.77])
        truth = sim(doe, between).float()
    err_coarse = float((coarse(between) - truth).abs().sum((-1, -2)).max())
    err_fine = float((fine(between) - truth).abs().sum((-1, -2)).max())
    assert err_fine < err_coarse / 4
    assert err_fine < 0.05  # L1 distance of energy-normalized PSFs
    with pytest.raises(EdofprojError, match="outside"):
        fine(np.array([0.9]))


# ----------------------------------------------------------------------------- camera, schedule, clipping


def test_camera_noise_has_the_configured_strength_and_8bit_levels():
    clean = torch.full((1, 3, 64, 64), 0.5)
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(0))
    noisy = camera_capture(clean, noise, sigma=0.02)
    assert abs(float((noisy - clean).std()) - 0.02) < 0.002
    x = torch.linspace(-0.2, 1.2, 101, requires_grad=True)
    q = quantize_8bit_ste(x)
    levels = q.detach() * 255
    assert torch.allclose(levels, levels.round(), atol=1e-4) and q.min() >= 0 and q.max() <= 1
    q.sum().backward()
    assert torch.equal(x.grad, torch.ones_like(x))  # straight-through
    assert torch.equal(camera_capture(clean), clean)


def test_learning_rate_decays_exponentially_to_the_final_fraction():
    param = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.Adam([param], lr=1e-3)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, exponential_decay(150, 0.99**150))
    lrs = []
    for _ in range(150):
        opt.step()
        sched.step()
        lrs.append(opt.param_groups[0]["lr"])
    assert lrs[0] == pytest.approx(1e-3 * 0.99)
    assert lrs[-1] == pytest.approx(1e-3 * 0.99**150)


def test_warm_up_rises_linearly_then_joins_the_decay():
    schedule = exponential_decay(100, 0.5, warmup_steps=10)
    assert schedule(0) == pytest.approx(0.1)
    assert schedule(4) == pytest.approx(0.5 * 0.5**0.04)
    assert schedule(9) == pytest.approx(0.5**0.09)
    assert schedule(50) == pytest.approx(0.5**0.5)
    assert exponential_decay(100, 0.5)(0) == 1.0


def test_gradient_clipping_limits_the_norm_and_reports_it():
    p = torch.nn.Parameter(torch.zeros(4))
    p.grad = torch.tensor([3.0, 4.0, 0.0, 0.0])
    norm = _clip([p], 1.0)
    assert float(norm) == pytest.approx(5.0)
    assert float(p.grad.norm()) == pytest.approx(1.0, rel=1e-5)
    p.grad = torch.tensor([3.0, 4.0, 0.0, 0.0])
    assert float(_clip([p], 0.0)) == pytest.approx(5.0) and float(p.grad.norm()) == pytest.approx(5.0)


# ----------------------------------------------------------------------------- precision and layout


def test_auto_precision_is_bf16_exactly_where_the_device_computes_it_natively(monkeypatch):
    from edofproj.training import end_to_end

    cpu = torch.device("cpu")
    assert end_to_end.resolve_mixed_precision("none", cpu) == "none"
    assert end_to_end.resolve_mixed_precision("bf16", cpu) == "bf16"
    for native in (False, True):
        monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda native=native: native)
        monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: False)
        assert end_to_end.resolve_mixed_precision("auto", cpu) == ("bf16" if native else "none")


def test_a_bf16_step_is_deterministic_and_close_to_float32():
    """The network under bf16 autocast: the same inputs give bit-identical outputs (exact resume relies on
    it), and the compensated projection differs from float32 by bf16 rounding only."""
    torch.manual_seed(0)
    net = build_network(tiny_config().net)
    with torch.no_grad():  # a network that does something: random head weights instead of zeros
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    psf = torch.full((1, 1, 3, 3), 1 / 9.0)
    target = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    source = lambda depths_m: psf.expand(len(depths_m), 3, 3, 3)  # noqa: E731
    runs = {}
    for precision in ("none", "bf16", "bf16"):
        model = EndToEndProjector(source, net, mixed_precision=precision)
        runs.setdefault(precision, []).append(model(target, np.array([0.5, 0.6])).projected)
    assert torch.equal(runs["bf16"][0], runs["bf16"][1])
    difference = (runs["bf16"][0] - runs["none"][0]).abs().max().item()
    assert 0 < difference < 0.02  # bf16 keeps 8 significant bits (2^-8 = 0.004 relative)


def test_the_unet_keeps_its_weights_channels_last_and_returns_nchw():
    net = build_network(tiny_config().net)
    convolutions = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    assert convolutions and all(m.weight.is_contiguous(memory_format=torch.channels_last) for m in convolutions)
    target = torch.rand(1, 3, 20, 28)
    out = net(target, target)
    assert out.shape == target.shape and out.is_contiguous()
    assert torch.equal(out, target)  # untrained: the identity, whatever the layout
