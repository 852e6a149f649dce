"""VGG16/AlexNet stacks with torchvision names, L2 pooling, DISTS, LPIPS, weight lookup."""

import numpy as np
import pytest
import torch
from scipy.ndimage import correlate
from skimage import data
from torch.nn import functional as F

from edofproj import metrics
from edofproj.errors import EdofprojError
from edofproj.perceptual import (
    DISTS,
    LPIPS,
    L2Pooling,
    PerceptualWeightsMissing,
    alexnet_backbone,
    dists_backbone,
    vgg16_backbone,
)
from edofproj.perceptual import weights as weight_files
from fake_backbones import VGG16_CONVS, torchvision_style_state


@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory):
    """A folder with test-made torchvision-format VGG16 and AlexNet weight files."""
    folder = tmp_path_factory.mktemp("weights")
    torch.save(torchvision_style_state("vgg16"), folder / "vgg16-397923af.pth")
    torch.save(torchvision_style_state("alexnet"), folder / "alexnet-owt-7be5be79.pth")
    return folder


@pytest.fixture
def empty_hub(tmp_path, monkeypatch):
    """Point torch's hub cache at an empty folder (so real downloaded weights are not found)."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    return tmp_path


def photo(size=32):
    image = data.astronaut()[40 : 40 + 2 * size : 2, 100 : 100 + 2 * size : 2] / 255.0
    return torch.tensor(image, dtype=torch.float32).permute(2, 0, 1)[None]


def noisy(image, sigma, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (image + sigma * torch.randn(image.shape, generator=gen)).clamp(0, 1)


def test_backbones_have_torchvision_names_and_sizes():
    vgg, alex = vgg16_backbone(), alexnet_backbone()
    vgg_names = {f"features.{i}.{p}" for i, _, _ in VGG16_CONVS for p in ("weight", "bias")}
    assert set(vgg.state_dict()) == vgg_names
    # torchvision's vgg16 has 138,357,544 parameters, 123,642,856 of them in the classifier
    assert sum(p.numel() for p in vgg.parameters()) == 138_357_544 - 123_642_856
    # alexnet: 61,100,840 in total, 58,631,144 in the classifier
    assert sum(p.numel() for p in alex.parameters()) == 61_100_840 - 58_631_144
    assert not any(p.requires_grad for p in vgg.parameters())


def test_vgg_loads_torchvision_state_dict_into_the_right_layers():
    state = torchvision_style_state("vgg16", seed=1)
    backbone = vgg16_backbone()
    backbone.load_torchvision_state_dict(state)
    x = torch.rand(1, 3, 20, 24)
    relu1_2, relu2_2 = backbone(x)[:2]
    # independent forward with the state dict's tensors
    h = F.relu(F.conv2d(x, state["features.0.weight"], state["features.0.bias"], padding=1))
    h = F.relu(F.conv2d(h, state["features.2.weight"], state["features.2.bias"], padding=1))
    torch.testing.assert_close(relu1_2, h, rtol=1e-5, atol=1e-5)
    h = F.max_pool2d(h, 2)
    h = F.relu(F.conv2d(h, state["features.5.weight"], state["features.5.bias"], padding=1))
    h = F.relu(F.conv2d(h, state["features.7.weight"], state["features.7.bias"], padding=1))
    torch.testing.assert_close(relu2_2, h, rtol=1e-5, atol=1e-5)
    shapes = [tuple(f.shape) for f in backbone(torch.rand(1, 3, 64, 64))]
    assert shapes == [(1, 64, 64, 64), (1, 128, 32, 32), (1, 256, 16, 16), (1, 512, 8, 8), (1, 512, 4, 4)]


def test_backbone_rejects_a_file_of_another_architecture(tmp_path):
    state = torchvision_style_state("alexnet")
    with pytest.raises(EdofprojError, match="not a torchvision vgg16 weight file"):
        vgg16_backbone().load_torchvision_state_dict(state)
    state = torchvision_style_state("vgg16")
    state["features.0.weight"] = torch.zeros(64, 3, 5, 5)
    with pytest.raises(EdofprojError, match="shape"):
        vgg16_backbone().load_torchvision_state_dict(state)
    (tmp_path / "junk.pth").write_bytes(b"not a pickle")
    with pytest.raises(EdofprojError, match="cannot read"):
        vgg16_backbone().load_torchvision_weights(tmp_path / "junk.pth")


def test_l2_pooling_matches_scipy():
    x = torch.rand(1, 2, 9, 12, dtype=torch.float64)
    window = np.outer([0.5, 1.0, 0.5], [0.5, 1.0, 0.5]) / 4.0
    out = L2Pooling()(x)
    for channel in range(2):
        squared = x[0, channel].numpy() ** 2
        expected = np.sqrt(correlate(squared, window, mode="constant")[::2, ::2] + 1e-12)
        np.testing.assert_allclose(out[0, channel].numpy(), expected, rtol=1e-6)
    constant = L2Pooling()(torch.full((1, 1, 8, 8), 0.7))
    torch.testing.assert_close(constant[..., 1:, 1:], torch.full((1, 1, 3, 3), 0.7))


@pytest.fixture(scope="module")
def random_dists():
    """DISTS with test-made VGG16 weights and the published alpha/beta."""
    backbone = dists_backbone()
    backbone.load_torchvision_state_dict(torchvision_style_state("vgg16"))
    alpha_beta = weight_files.load_state_dict_file(weight_files.metric_weights_path("dists"))
    return DISTS(backbone, alpha_beta["alpha"], alpha_beta["beta"])


def test_dists_is_zero_for_identical_images_and_grows_with_noise(random_dists):
    image = photo()
    assert abs(random_dists(image, image).item()) < 1e-6
    batch = torch.cat([noisy(image, s) for s in (0.02, 0.05, 0.1, 0.2)])
    values = random_dists(batch, image.expand(4, -1, -1, -1)).tolist()
    assert all(a < b for a, b in zip(values, values[1:])), values
    assert 0 < values[0] and values[-1] < 1
    assert random_dists(image, batch[2:3]).item() == pytest.approx(values[2], abs=1e-6)  # symmetric


def test_dists_passes_gradients_to_the_input(random_dists):
    image = photo()
    pred = noisy(image, 0.1).requires_grad_(True)
    random_dists(pred, image).sum().backward()
    assert pred.grad is not None and pred.grad.abs().sum() > 0


def test_dists_and_lpips_load_from_weights_dir(weights_dir, empty_hub):
    dists = metrics.dists(weights_dir=weights_dir)
    image = photo()
    assert abs(dists(image, image).item()) < 1e-6
    for net in ("alex", "vgg"):
        lpips = metrics.lpips(net, weights_dir=weights_dir)
        assert lpips(image, image).abs().max().item() < 1e-6
        batch = torch.cat([noisy(image, s) for s in (0.02, 0.1, 0.3)])
        values = lpips(batch, image.expand(3, -1, -1, -1)).tolist()
        assert all(a < b for a, b in zip(values, values[1:])), (net, values)
    assert metrics.available_perceptual_metrics(weights_dir) == {"dists": True, "lpips-alex": True, "lpips-vgg": True}


def test_lpips_uses_the_published_linear_weights(weights_dir, empty_hub):
    lpips = LPIPS.load("vgg", weights_dir)
    linear = weight_files.load_state_dict_file(weight_files.metric_weights_path("lpips-vgg"))
    for index, weight in enumerate(lpips.layer_weights):
        torch.testing.assert_close(weight.flatten(), linear[f"lin{index}.model.1.weight"].flatten())


def test_missing_backbone_weights_name_the_file_and_how_to_get_it(empty_hub):
    with pytest.raises(PerceptualWeightsMissing) as info:
        metrics.dists()
    message = str(info.value)
    assert "vgg16-397923af.pth" in message and "edofproj weights fetch --backbone vgg16" in message
    assert str(empty_hub / "torch_home" / "hub" / "checkpoints") in message
    assert "\n" not in message
    with pytest.raises(PerceptualWeightsMissing, match="alexnet-owt-7be5be79.pth"):
        metrics.lpips("alex")
    assert isinstance(info.value, EdofprojError)
    assert metrics.available_perceptual_metrics() == {"dists": False, "lpips-alex": False, "lpips-vgg": False}


def test_missing_torchmetrics_data_is_reported(weights_dir, monkeypatch):
    monkeypatch.setattr(weight_files, "_torchmetrics_dir", lambda: None)
    with pytest.raises(PerceptualWeightsMissing, match="dists_models/weights.pt"):
        metrics.dists(weights_dir=weights_dir)
    assert metrics.available_perceptual_metrics(weights_dir)["lpips-vgg"] is False


def test_unknown_perceptual_names_raise():
    with pytest.raises(EdofprojError, match="allowed: dists, lpips-alex, lpips-vgg"):
        metrics.perceptual_metric("lpips-squeeze")
    with pytest.raises(EdofprojError, match="allowed: alex, vgg"):
        metrics.lpips("squeeze")


REAL = metrics.available_perceptual_metrics()


@pytest.mark.skipif(not REAL["dists"], reason="torchvision's vgg16-397923af.pth is not in the hub cache")
def test_real_dists_ranks_blur_levels():
    dists = metrics.dists()
    image = photo(128)
    blurred = [F.avg_pool2d(image, k, stride=1, padding=k // 2, count_include_pad=False) for k in (3, 5, 9)]
    values = [dists(b, image).item() for b in blurred]
    assert abs(dists(image, image).item()) < 1e-6
    assert all(a < b for a, b in zip(values, values[1:])) and 0 < values[0] < values[-1] < 1


@pytest.mark.skipif(not REAL["lpips-alex"], reason="torchvision's alexnet-owt-7be5be79.pth is not in the hub cache")
def test_real_lpips_ranks_noise_levels():
    lpips = metrics.lpips("alex")
    image = photo(128)
    values = [lpips(noisy(image, s), image).item() for s in (0.02, 0.1, 0.3)]
    assert all(a < b for a, b in zip(values, values[1:])) and values[-1] < 1.5
