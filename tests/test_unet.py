"""Compensation U-Net (paper Fig. 5): identity at start, any size, export, presets."""

import io
import warnings

import numpy as np
import pytest
import torch

from edofproj.compensation.unet import UNET_WIDTH_PRESETS, CompensationUNet, width_preset
from edofproj.config import ConfigError
from edofproj.errors import EdofprojError
from edofproj.net_config import UNetConfig

SMALL = [4, 8, 8, 16, 16, 16, 16]  # 7 scales, few channels: fast tests


def images(height, width, batch=1, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(batch, 3, height, width, generator=gen), torch.rand(batch, 3, height, width, generator=gen))


def trained_looking(net, seed=0):
    """Randomize the zero-initialized head so that the output is not the identity."""
    torch.manual_seed(seed)
    torch.nn.init.normal_(net.head.weight, std=0.2)
    torch.nn.init.normal_(net.head.bias, std=0.05)
    return net.eval()


def expected_parameter_count(widths, in_channels=6, out_channels=3, downsampling="conv", upsampling="transpose"):
    """Closed form: k*k*c_in*c_out + c_out per convolution."""
    conv = lambda k, c_in, c_out: k * k * c_in * c_out + c_out  # noqa: E731
    block = lambda c_in, c_out: conv(3, c_in, c_out) + conv(3, c_out, c_out)  # noqa: E731
    total = block(in_channels, widths[0]) + conv(1, widths[0], out_channels)
    for fine, coarse in zip(widths[:-1], widths[1:]):
        total += block(fine, coarse) + block(2 * fine, fine)
        total += conv(3, fine, fine) if downsampling == "conv" else 0
        total += conv(2, coarse, fine) if upsampling == "transpose" else conv(3, coarse, fine)
    return total


@pytest.mark.parametrize("size", [(600, 800), (37, 53), (1, 1), (65, 64)])
def test_untrained_network_is_exactly_the_identity(size):
    net = CompensationUNet(SMALL)
    target, captured = images(*size)
    with torch.no_grad():
        out = net(target, captured)
    assert torch.equal(out, target)


@pytest.mark.parametrize("size", [(600, 800), (37, 53), (3, 130)])
@pytest.mark.parametrize("padding_mode", ["replicate", "reflect"])
def test_any_size_equals_explicit_padding_then_crop(size, padding_mode):
    """The net pads bottom/right to a multiple of 64 and crops back: same as NumPy padding."""
    height, width = size
    if padding_mode == "reflect" and height < 64 - height % 64:
        with pytest.raises(EdofprojError, match="padding_mode=replicate"):
            CompensationUNet(SMALL, padding_mode=padding_mode)(*images(height, width))
        return
    net = trained_looking(CompensationUNet(SMALL, padding_mode=padding_mode))
    target, captured = images(height, width)
    pad = ((0, 0), (0, 0), (0, -height % 64), (0, -width % 64))
    numpy_mode = {"replicate": "edge", "reflect": "reflect"}[padding_mode]
    padded_t = torch.from_numpy(np.pad(target.numpy(), pad, mode=numpy_mode))
    padded_c = torch.from_numpy(np.pad(captured.numpy(), pad, mode=numpy_mode))
    with torch.no_grad():
        out = net(target, captured)
        reference = net(padded_t, padded_c)[..., :height, :width]
    assert out.shape == target.shape
    assert (out - target).abs().max() > 1e-3
    torch.testing.assert_close(out, reference, rtol=0, atol=1e-6)


def test_seven_scales_reach_one_64th_of_the_size():
    net = CompensationUNet(SMALL)
    shapes = []
    net.encoder[-1].register_forward_hook(lambda m, i, o: shapes.append(tuple(o.shape)))
    net(*images(128, 192))
    assert shapes == [(1, SMALL[-1], 2, 3)]
    assert len(net.down) == len(net.up) == 6


@pytest.mark.parametrize("downsampling", ["conv", "maxpool"])
@pytest.mark.parametrize("upsampling", ["transpose", "bilinear"])
def test_parameter_count_matches_the_architecture(downsampling, upsampling):
    net = CompensationUNet(SMALL, downsampling=downsampling, upsampling=upsampling)
    assert sum(p.numel() for p in net.parameters()) == expected_parameter_count(
        SMALL, downsampling=downsampling, upsampling=upsampling
    )
    trained_looking(net)
    target, captured = images(40, 70)
    assert net(target, captured).shape == target.shape


def test_zero_initialized_network_learns():
    """Gradients reach the whole net through the zero head: it learns a brightness offset."""
    torch.manual_seed(0)
    net = CompensationUNet([4, 8, 8])
    optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
    target, captured = images(32, 32, batch=2)
    losses = []
    for _ in range(30):
        optimizer.zero_grad()
        loss = torch.mean((net(target, captured) - (target + 0.2)) ** 2)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[0] == pytest.approx(0.04, rel=1e-5)
    assert losses[-1] < 0.2 * losses[0]
    assert any(p.grad.abs().sum() > 0 for p in net.encoder[0].parameters())


def test_channels_last_gives_the_same_output():
    net = trained_looking(CompensationUNet(SMALL))
    target, captured = images(50, 70)
    with torch.no_grad():
        reference = net(target, captured)
        net_cl = net.to(memory_format=torch.channels_last)
        out = net_cl(
            target.contiguous(memory_format=torch.channels_last), captured.contiguous(memory_format=torch.channels_last)
        )
    torch.testing.assert_close(out, reference, rtol=1e-5, atol=1e-5)


def test_onnx_export_opset17_with_dynamic_size():
    onnxruntime = pytest.importorskip("onnxruntime")
    net = trained_looking(CompensationUNet(SMALL, downsampling="maxpool", upsampling="bilinear"))
    buffer = io.BytesIO()
    axes = {0: "batch", 2: "height", 3: "width"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            images(64, 64),
            buffer,
            opset_version=17,
            dynamo=False,
            input_names=["target", "captured"],
            output_names=["projector_input"],
            dynamic_axes={"target": axes, "captured": axes, "projector_input": axes},
        )
    session = onnxruntime.InferenceSession(buffer.getvalue(), providers=["CPUExecutionProvider"])
    for size in [(64, 64), (45, 77)]:
        target, captured = images(*size, batch=2, seed=3)
        out = session.run(None, {"target": target.numpy(), "captured": captured.numpy()})[0]
        with torch.no_grad():
            reference = net(target, captured).numpy()
        assert out.shape == (2, 3, *size)
        np.testing.assert_allclose(out, reference, atol=1e-5)


def test_torchscript_trace_generalizes_to_other_sizes():
    net = trained_looking(CompensationUNet(SMALL))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traced = torch.jit.trace(net, images(64, 96))
    target, captured = images(37, 129, seed=5)
    with torch.no_grad():
        torch.testing.assert_close(traced(target, captured), net(target, captured), rtol=0, atol=1e-6)


def test_presets_and_config():
    assert UNET_WIDTH_PRESETS["default"] == UNetConfig().widths
    assert all(len(w) == 7 for w in UNET_WIDTH_PRESETS.values())
    count = lambda name: expected_parameter_count(UNET_WIDTH_PRESETS[name])  # noqa: E731
    assert count("fast") < count("default") < count("paper")
    assert width_preset("fast") == UNET_WIDTH_PRESETS["fast"]
    with pytest.raises(EdofprojError, match="allowed: paper, default, fast"):
        width_preset("huge")
    cfg = UNetConfig(widths=[4, 8, 16], downsampling="maxpool", upsampling="bilinear", padding_mode="reflect")
    net = CompensationUNet.from_config(cfg)
    assert net.widths == [4, 8, 16] and net.padding_mode == "reflect"
    assert isinstance(net.down[0], torch.nn.MaxPool2d)


def test_bad_arguments_raise_one_line_errors():
    with pytest.raises(ConfigError, match="did you mean 'maxpool'"):
        UNetConfig(downsampling="maxpol").validate()
    with pytest.raises(ConfigError, match="positive integer"):
        UNetConfig(widths=[16]).validate()
    with pytest.raises(EdofprojError, match="upsampling='nearest' is not one of transpose, bilinear"):
        CompensationUNet(SMALL, upsampling="nearest")
    with pytest.raises(EdofprojError, match="same shape"):
        CompensationUNet(SMALL)(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 9))


@pytest.mark.parametrize("height, width", [(600, 800), (37, 53)])
def test_space_to_depth_variant_is_identity_at_start_and_keeps_every_pixel(height, width):
    torch.manual_seed(0)
    net = CompensationUNet([8, 12, 16], space_to_depth=4)
    target, captured = torch.rand(1, 3, height, width), torch.rand(1, 3, height, width)
    assert torch.equal(net(target, captured), target)
    # after a perturbation of the head, neighbouring pixels inside one 4x4 block differ: the
    # pixel shuffle gives every output pixel its own value
    with torch.no_grad():
        net.head.weight.normal_(0, 0.1)
    residual = net(target, captured) - target
    assert residual.shape == target.shape
    assert not torch.allclose(residual[..., 0:4:2, 0:4:2], residual[..., 1:4:2, 1:4:2])
