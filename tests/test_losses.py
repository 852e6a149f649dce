"""Training loss alpha * MSE + beta * perceptual (paper Eq. 12)."""

import numpy as np
import pytest
import torch
from skimage import data
from skimage.metrics import structural_similarity

from edofproj.config import ConfigError, LossConfig
from edofproj.errors import EdofprojError
from edofproj.perceptual import PerceptualWeightsMissing
from edofproj.training.losses import CompensationLoss, build_loss
from fake_backbones import torchvision_style_state


def photo_pair(size=128, noise=0.1, seed=0):
    image = data.chelsea()[:size, 100 : 100 + size] / 255.0
    rng = np.random.default_rng(seed)
    distorted = np.clip(image + noise * rng.standard_normal(image.shape), 0, 1)
    to_tensor = lambda a: torch.tensor(a, dtype=torch.float32).permute(2, 0, 1)[None]  # noqa: E731
    return to_tensor(distorted), to_tensor(image)


def test_default_config_is_the_paper_weighting_with_ms_ssim():
    loss = build_loss(LossConfig())
    assert (loss.alpha, loss.beta, loss.perceptual_name) == (1.0, 0.05, "ms-ssim")


def test_mse_only_closed_form():
    loss = build_loss(LossConfig(alpha=2.0, beta=0.05, perceptual="none"))
    target = torch.full((2, 3, 16, 16), 0.5)
    assert loss(target + 0.1, target).item() == pytest.approx(2.0 * 0.01, rel=1e-5)
    assert loss(target, target).item() == 0.0


def test_ssim_term_matches_skimage():
    pred, target = photo_pair(64)
    loss = build_loss(LossConfig(alpha=1.0, beta=0.5, perceptual="ssim"))
    terms = loss.terms(pred, target)
    hwc = lambda t: t[0].permute(1, 2, 0).double().numpy()  # noqa: E731
    reference = structural_similarity(
        hwc(pred),
        hwc(target),
        channel_axis=2,
        data_range=1.0,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
    )
    mse = float(((hwc(pred) - hwc(target)) ** 2).mean())
    assert terms["perceptual"].item() == pytest.approx(1 - reference, abs=1e-4)
    assert terms["mse"].item() == pytest.approx(mse, rel=1e-5)
    assert terms["total"].item() == pytest.approx(mse + 0.5 * (1 - reference), abs=1e-4)


def test_ms_ssim_loss_on_128_crops_is_zero_for_identity_and_trainable():
    pred, target = photo_pair(128)
    loss = build_loss(LossConfig(perceptual="ms-ssim"))
    assert loss(target, target).item() == pytest.approx(0.0, abs=1e-6)
    variable = pred.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([variable], lr=0.01)
    start = loss(variable, target).item()
    for _ in range(10):
        optimizer.zero_grad()
        value = loss(variable, target)
        value.backward()
        assert torch.isfinite(variable.grad).all()
        optimizer.step()
    assert loss(variable, target).item() < 0.8 * start


def test_perceptual_term_is_averaged_over_the_batch():
    pred_a, target_a = photo_pair(64, noise=0.05, seed=1)
    pred_b, target_b = photo_pair(64, noise=0.3, seed=2)
    loss = build_loss(LossConfig(alpha=0.0, beta=1.0, perceptual="ssim"))
    both = loss(torch.cat([pred_a, pred_b]), torch.cat([target_a, target_b]))
    separate = (loss(pred_a, target_a) + loss(pred_b, target_b)).item() / 2
    assert both.item() == pytest.approx(separate, rel=1e-5)


def test_dists_loss_without_weights_raises_unless_unused(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    with pytest.raises(PerceptualWeightsMissing, match="vgg16-397923af.pth"):
        build_loss(LossConfig(perceptual="dists"))
    loss = build_loss(LossConfig(perceptual="dists", beta=0.0))  # nothing to load
    pred, target = photo_pair(32)
    assert loss(pred, target).item() == pytest.approx(torch.mean((pred - target) ** 2).item(), rel=1e-6)


def test_dists_loss_with_weights_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty"))
    torch.save(torchvision_style_state("vgg16"), tmp_path / "vgg16-397923af.pth")
    loss = build_loss(LossConfig(perceptual="dists", weights_dir=str(tmp_path)))
    pred, target = photo_pair(32)
    assert loss(target, target).item() == pytest.approx(0.0, abs=1e-6)
    variable = pred.clone().requires_grad_(True)
    terms = loss.terms(variable, target)
    terms["total"].backward()
    assert terms["perceptual"].item() > 0
    expected = terms["mse"].item() + 0.05 * terms["perceptual"].item()
    assert terms["total"].item() == pytest.approx(expected, rel=1e-6)
    assert variable.grad.abs().sum() > 0


def test_bad_loss_settings_raise():
    with pytest.raises(ConfigError, match="did you mean 'dists'"):
        LossConfig(perceptual="dist").validate()
    with pytest.raises(EdofprojError, match=">= 0"):
        CompensationLoss(alpha=-1.0)
    with pytest.raises(EdofprojError, match="same shape"):
        build_loss(LossConfig())(torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 31))
