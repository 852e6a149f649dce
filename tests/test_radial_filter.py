"""The learned radial Fourier pre-filter: closed-form responses, symmetry, and its place in the U-Net."""

import math

import numpy as np
import pytest
import torch

from edofproj.compensation.radial_filter import GAIN_SCALE, RHO_MAX, RadialFourierFilter
from edofproj.compensation.unet import CompensationUNet
from edofproj.config import ConfigError, load_config
from edofproj.errors import EdofprojError


def test_starts_as_identity():
    image = torch.rand(2, 3, 37, 50)
    assert torch.allclose(RadialFourierFilter(3, 16)(image), image, atol=1e-6)


def test_constant_gain_scales_the_image():
    layer = RadialFourierFilter(3, 8, margin_px=5)
    with torch.no_grad():
        layer.gain.fill_(0.15)  # H = 1 + GAIN_SCALE * 0.15 at every frequency
    image = torch.rand(1, 3, 20, 24)
    assert torch.allclose(layer(image), (1 + GAIN_SCALE * 0.15) * image, atol=1e-5)


@pytest.mark.parametrize("cycles_x, cycles_y", [(3, 0), (5, 4), (0, 7)])
def test_cosine_is_scaled_by_the_interpolated_transfer_function(cycles_x, cycles_y):
    """A cosine of integer cycles over the frame (no margin, so exactly periodic) is an
    eigenfunction: out = H(rho) in, with H from np.interp of the node values."""
    height, width = 48, 64
    nodes = np.random.default_rng(1).normal(size=(1, 12)) * 0.05
    layer = RadialFourierFilter(1, 12, margin_px=0)
    with torch.no_grad():
        layer.gain.copy_(torch.from_numpy(nodes))
    y, x = np.mgrid[0:height, 0:width]
    wave = np.cos(2 * np.pi * (cycles_x * x / width + cycles_y * y / height))
    rho = math.hypot(cycles_x / width, cycles_y / height)
    gain = 1 + GAIN_SCALE * np.interp(rho, np.linspace(0, RHO_MAX, 12), nodes[0])
    out = layer(torch.from_numpy(wave).float()[None, None])[0, 0].detach().numpy()
    np.testing.assert_allclose(out, gain * wave, atol=1e-4)


def test_rotational_symmetry():
    layer = RadialFourierFilter(3, 10, margin_px=8)
    with torch.no_grad():
        layer.gain.normal_(0, 0.1)
    image = torch.rand(1, 3, 40, 40)
    assert torch.allclose(layer(image.transpose(-1, -2)), layer(image).transpose(-1, -2), atol=1e-5)
    assert torch.allclose(layer(image.flip(-1)), layer(image).flip(-1), atol=1e-5)


def test_unet_with_prefilter_starts_as_identity_and_trains_the_filter():
    net = CompensationUNet([4, 8], prefilter_bins=6)
    target = torch.rand(1, 3, 24, 20)
    out = net(target, target * 0.5)
    assert torch.allclose(out, target, atol=1e-5)
    out.square().sum().backward()
    assert net.prefilter.gain.grad.abs().sum() > 0


def test_config_and_bad_values():
    cfg = load_config("cpu", ["net.prefilter_bins=16", "net.linear_base=none"])
    assert CompensationUNet.from_config(cfg.net).prefilter is not None
    with pytest.raises(ConfigError, match="prefilter_bins"):
        load_config("cpu", ["net.prefilter_bins=1"])
    with pytest.raises(EdofprojError, match="bins"):
        RadialFourierFilter(3, 1)


def test_inference_cache_follows_parameter_updates():
    layer = RadialFourierFilter(3, 6, margin_px=2)
    image = torch.rand(1, 3, 16, 16)
    with torch.no_grad():
        assert torch.allclose(layer(image), image, atol=1e-6)
        layer.gain.fill_(0.1)  # an in-place update (as an optimizer step) must not reuse the old H
        assert torch.allclose(layer(image), 2 * image, atol=1e-5)


def test_network_description_names_the_prefilter():
    from edofproj.compensation.registry import describe_network

    prefiltered = load_config("cpu", ["net.prefilter_bins=48", "net.linear_base=none", "net.widths=[16,32,64,128]"]).net
    assert describe_network(prefiltered) == "U-Net 16-128 (4 scales) + radial pre-filter (48 nodes)"
    assert describe_network(load_config("cpu", ["net.widths=[16,32,64,128]"]).net) == (
        "U-Net 16-128 (4 scales) as a correction of at most 0.2 on its optics' depth-ensemble linear filter"
    )
    # the same words describe lens+net, whose optics is the bare lens: they must not name a DOE
    lens_net = load_config("cpu", ["doe.kind=lens"]).net
    assert "DOE" not in describe_network(lens_net)
    assert describe_network(load_config("paper").net) == "U-Net 32-256 (7 scales)"


def test_radial_frequency_grid_equals_fftfreq_bit_for_bit():
    """The grid is built from arange (ONNX has no fftfreq) and must not change any result."""
    from edofproj.compensation.radial_filter import radial_frequency

    for height, width in ((1, 1), (7, 12), (150, 200), (182, 232), (320, 320), (664, 864), (1088, 2080)):
        expected = torch.sqrt(torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.rfftfreq(width)[None, :] ** 2)
        assert torch.equal(radial_frequency(height, width), expected), (height, width)
