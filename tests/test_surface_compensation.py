"""Compensation that knows the surface: the achievable goal, the photometric baseline, the
surface-aware network (untrained = the photometric-then-defocus cascade) and training on random surfaces."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.compensation.achievable import (
    MIN_GAIN,
    SurfaceRangeWarning,
    achievable_goal,
    clipped_fraction,
    require_visible,
    warn_if_out_of_reach,
)
from edofproj.compensation.photometric import photometric_compensation
from edofproj.compensation.registry import build_network, describe_network
from edofproj.compensation.surface_net import SurfaceAwareNet
from edofproj.compensation.unet import CompensationUNet
from edofproj.config import Config, apply_overrides
from edofproj.data.photos import BUILTIN_PHOTOS
from edofproj.data.textures import HELD_OUT_PHOTOS, TrainingSurfaces, builtin_texture_names, surface_reflectance
from edofproj.errors import EdofprojError
from edofproj.imaging.projection import project
from edofproj.runs import load_run
from edofproj.training.sampling import BatchShard, sample_surfaces
from edofproj.training.trainer import train
from tiny_configs import TINY_TRAINING

H, W = 24, 32


def texture(seed=0, low=0.1):
    return low + (1 - low) * torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(seed))


def gaussian_psf(sigma, size=9):
    r2 = (torch.arange(size) - size // 2)[:, None] ** 2 + (torch.arange(size) - size // 2)[None, :] ** 2
    kernel = torch.exp(-r2 / (2 * sigma**2))
    return (kernel / kernel.sum())[None, None].repeat(1, 3, 1, 1)


def test_goal_on_a_white_screen_is_the_target():
    target = torch.rand(2, 3, H, W)
    goal = achievable_goal(target, torch.ones(1, 3, H, W), torch.zeros(1, 3, 1, 1))
    torch.testing.assert_close(goal.image, target)
    assert torch.all(goal.gain == 1) and torch.all(goal.floor == 0)


def test_goal_on_a_uniform_coloured_surface_is_the_closed_form():
    """s = (0.3, 0.6, 0.9), a = (0.05, 0.1, 0): floor f = a, gain k = min_c s_c = 0.3, g = a + 0.3 t;
    every pixel is reachable."""
    rho = torch.tensor([0.3, 0.6, 0.9]).reshape(1, 3, 1, 1).expand(1, 3, H, W)
    ambient = torch.tensor([0.05, 0.1, 0.0]).reshape(1, 3, 1, 1)
    target = torch.rand(1, 3, H, W)
    goal = achievable_goal(target, rho, ambient)
    torch.testing.assert_close(goal.image, ambient + 0.3 * target)
    assert float(clipped_fraction(goal.image, rho, ambient)) == 0.0


def test_a_few_dark_pixels_do_not_set_the_contrast():
    rho = torch.full((1, 3, H, W), 0.8)
    rho[..., 0, :6] = 0.05  # 6 of 768 pixels (0.8 %): below the 2 % quantile
    target = torch.ones(1, 3, H, W)
    goal = achievable_goal(target, rho, torch.zeros(1, 3, 1, 1))
    assert float(goal.gain) == pytest.approx(0.8)
    assert float(clipped_fraction(goal.image, rho, torch.zeros(1, 3, 1, 1))) == pytest.approx(6 / (H * W))
    assert require_visible(rho, torch.zeros(1, 3, 1, 1)) == pytest.approx(0.8)


def test_a_target_with_many_pixels_out_of_reach_is_warned():
    """Ambient 0.3 on three disjoint sets of 1.9 % of the pixels, one per colour: each colour's floor
    stays 0 (its 98th percentile), so a black target is out of reach on 3 x 14 of 768 pixels (5.5 %)."""
    rho = torch.full((1, 3, H, W), 0.8)
    ambient = torch.zeros(1, 3, H, W)
    per_colour = int(0.019 * H * W)
    for c in range(3):
        ambient.view(1, 3, -1)[0, c, c * per_colour : (c + 1) * per_colour] = 0.3
    goal = achievable_goal(torch.zeros(1, 3, H, W), rho, ambient)
    assert float(goal.gain) == pytest.approx(0.8)
    with pytest.warns(
        SurfaceRangeWarning, match=r"too dark for the target: 5\.[4-7] % of the pixels cannot be reached"
    ):
        warn_if_out_of_reach(goal, rho, ambient)


def test_a_dark_surface_that_can_still_show_an_image_is_warned_not_refused():
    dark = torch.full((1, 3, H, W), 0.03)  # 7.6 grey levels
    assert require_visible(dark, torch.zeros(1, 3, 1, 1)) == pytest.approx(0.03)
    goal = achievable_goal(torch.ones(1, 3, H, W), dark, torch.zeros(1, 3, 1, 1))
    with pytest.warns(SurfaceRangeWarning, match=r"too dark for the target: .*0\.030 .*SSIM and PSNR are inflated"):
        warn_if_out_of_reach(goal, dark, torch.zeros(1, 3, 1, 1))


@pytest.mark.parametrize(
    "rho, ambient",
    [
        (0.0, 0.0),  # a black object, or white and black captures swapped
        (0.0, 0.5),  # lit only by the room: nothing the projector does shows
        (0.01, 0.0),  # 1 % grey: 2.5 grey levels; SSIM's constants, not the projection, would be scored
    ],
)
def test_a_surface_that_cannot_show_an_image_is_refused_in_one_line(rho, ambient):
    """Its goal is nearly constant: every method would score SSIM ~1 (a silent wrong result)."""
    reflectance = torch.full((1, 3, H, W), rho)
    with pytest.raises(EdofprojError, match=r"^the surface cannot show an image: .* is 0\.0[01]0 of a white screen's"):
        require_visible(reflectance, torch.full((1, 3, 1, 1), ambient))
    assert (
        float(achievable_goal(torch.rand(1, 3, H, W), reflectance, torch.full((1, 3, 1, 1), ambient)).gain) < MIN_GAIN
    )


def test_photometric_compensation_is_exact_for_a_sharp_projector_but_not_through_blur():
    rho, ambient = texture(1), 0.05 * texture(2)
    target = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(3))
    goal = achievable_goal(target, rho, ambient).image
    light = photometric_compensation(goal, rho, ambient)
    impulse = torch.zeros(1, 3, 3, 3)
    impulse[..., 1, 1] = 1
    reachable = (goal >= ambient) & (goal <= ambient + rho)
    seen = rho * project(light, impulse) + ambient
    torch.testing.assert_close(seen[reachable], goal[reachable], atol=1e-5, rtol=0)
    blurred = rho * project(light, gaussian_psf(2.0)) + ambient
    assert float((blurred - goal)[..., 5:-5, 5:-5].abs().mean()) > 0.02  # the texture edges are not undone


def test_untrained_surface_net_is_the_photometric_then_defocus_cascade():
    inner = CompensationUNet([4, 8])
    with torch.no_grad():  # a non-trivial inner network
        for p in inner.parameters():
            p.add_(0.05 * torch.randn_like(p))
    net = SurfaceAwareNet(inner)
    rho, ambient = texture(4), 0.05 * texture(5)
    goal = achievable_goal(torch.rand(1, 3, H, W), rho, ambient).image
    captured = rho * project(goal, gaussian_psf(1.5)) + ambient
    expected = inner(((goal - ambient) / rho).clamp(0, 1), ((captured - ambient) / rho).clamp(0, 1))
    torch.testing.assert_close(net(goal, captured, rho, ambient), expected, atol=1e-5, rtol=0)
    # without a surface it is the inner network on the target itself
    target = torch.rand(1, 3, H, W)
    torch.testing.assert_close(net(target, captured), inner(target, captured), atol=1e-6, rtol=0)
    # and its head sees the surface: after a change of its last layer the reflectance changes the output
    with torch.no_grad():
        net.head[-1].weight.normal_(0, 0.1)
    assert not torch.allclose(net(goal, captured, rho, ambient), net(goal, captured, rho * 0.9, ambient))


def test_net_surface_input_wraps_any_architecture():
    cfg = apply_overrides(Config(), ["net.widths=[4,8]", "net.surface_input=true"])
    assert isinstance(build_network(cfg.net), SurfaceAwareNet)
    assert describe_network(cfg.net).endswith("with the surface as input")
    assert not isinstance(build_network(Config().net), SurfaceAwareNet)


def test_training_surfaces_are_valid_deterministic_and_never_the_held_out_photographs():
    surfaces = TrainingSurfaces()
    assert not set(HELD_OUT_PHOTOS) & set(surfaces.photos)
    assert set(surfaces.photos) | set(HELD_OUT_PHOTOS) == set(BUILTIN_PHOTOS)
    shard = BatchShard(0, 6, 6)
    rho, ambient = sample_surfaces(surfaces, 0, 1, shard, 32)
    again, _ = sample_surfaces(surfaces, 0, 1, shard, 32)
    assert torch.equal(rho, again)
    assert rho.shape == ambient.shape == (6, 3, 32, 32)
    assert float(rho.min()) >= 0 and float(rho.max()) <= 1 and float(ambient.min()) >= 0
    assert float(ambient.max()) <= 0.15 * 1.2 + 1e-6
    assert len({float(r.std()) for r in rho}) > 1  # different textures per sample


def test_builtin_textures_and_texture_files():
    for name in builtin_texture_names():
        rho = surface_reflectance(name, (40, 56))
        assert rho.shape == (1, 3, 40, 56)
        assert float(rho.min()) >= 0.1 - 1e-6 or name == "white"
        assert float(rho.max()) <= 1.0
    with pytest.raises(EdofprojError, match="neither a built-in texture"):
        surface_reflectance("marble-nowhere", (40, 56))


@pytest.mark.slow
def test_training_with_surfaces_runs_and_loads(tmp_path):
    cfg = apply_overrides(Config(), TINY_TRAINING + ["train.steps=2", "train.batch_size=2", "net.surface_input=true"])
    result = train(cfg, tmp_path / "run", progress=False)
    assert result.step == 2
    run = load_run(tmp_path / "run")
    assert isinstance(run.net, SurfaceAwareNet)
    assert np.isfinite([float(p.detach().sum()) for p in run.net.parameters()]).all()
