"""Network export: ONNX (dynamic H/W) and TorchScript match PyTorch; atomic; one-line CLI errors."""

import sys

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.compensation.export import export_network
from edofproj.compensation.onlineprodeb import OnlineProDebNet
from edofproj.compensation.unet import CompensationUNet
from edofproj.errors import EdofprojError

onnxruntime = pytest.importorskip("onnxruntime")


def small_unet(seed: int = 0) -> CompensationUNet:
    """A 3-scale U-Net whose zero-initialized head is randomized (so the output is not the identity)."""
    torch.manual_seed(seed)
    net = CompensationUNet([4, 8, 16])
    torch.nn.init.normal_(net.head.weight, std=0.3)
    return net.eval()


def inputs(height, width, seed=7):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, height, width, generator=g), torch.rand(1, 3, height, width, generator=g)


def test_onnx_matches_pytorch_at_other_sizes(tmp_path):
    net = small_unet()
    path = tmp_path / "net.onnx"
    worst = export_network(net, path, "onnx", height=48, width=64)
    assert 0.0 <= worst < 1e-4
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["target", "captured"]
    assert [o.name for o in session.get_outputs()] == ["projector_input"]
    for height, width in [(48, 64), (30, 75)]:
        target, captured = inputs(height, width)
        out = session.run(None, {"target": target.numpy(), "captured": captured.numpy()})[0]
        with torch.no_grad():
            reference = net(target, captured).numpy()
        assert out.shape == (1, 3, height, width)
        assert np.abs(reference - target.numpy()).max() > 1e-2  # a non-trivial network
        assert np.abs(out - reference).max() < 1e-4
    assert [p.name for p in tmp_path.iterdir()] == ["net.onnx"]  # no temporary files left


@pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated:DeprecationWarning")
def test_torchscript_matches_pytorch(tmp_path):
    net = small_unet(1)
    path = tmp_path / "net.pt"
    assert export_network(net, path, "torchscript", height=32, width=40) < 1e-4
    module = torch.jit.load(str(path))
    target, captured = inputs(32, 40)
    with torch.no_grad():
        assert torch.allclose(module(target, captured), net(target, captured), atol=1e-5)


@pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated:DeprecationWarning")
def test_fourier_filter_networks_export_to_torchscript_and_to_fixed_size_onnx(tmp_path):
    """A radial Fourier filter goes to ONNX through torch.export, for the
    export's frame size: ONNX Runtime's output matches PyTorch at that size, for the U-Net with a
    pre-filter and for the multi-rate network, and the file declares that size."""
    pytest.importorskip("onnxscript")
    from edofproj.compensation.multirate import MultirateCompensationNet

    torch.manual_seed(2)
    unet = CompensationUNet([4, 8], prefilter_bins=8).eval()
    torch.nn.init.normal_(unet.prefilter.gain, std=0.1)
    torch.nn.init.normal_(unet.head.weight, std=0.3)
    assert export_network(unet, tmp_path / "net.pt", "torchscript", height=32, width=40) < 1e-4
    multirates = []
    for bound in (0.0, 0.2):  # the unbounded form and the safe form (the realtime preset's)
        multirate = MultirateCompensationNet([4, 8], filter_bins=8, correction_bound=bound, correction_highpass_px=8.0)
        with torch.no_grad():
            multirate.prefilter.gain.normal_(0, 0.1)
            multirate.head.weight.normal_(0, 0.3)
            multirate.linear_gain.weight.normal_(0, 0.3)
            for local in multirate.local_filter:
                local.weight.normal_(0, 0.02)
        multirates.append(multirate.eval())
    cases = (
        ("unet", unet, (32, 40)),
        ("multirate", multirates[0], (36, 52)),
        ("safe_multirate", multirates[1], (36, 52)),
    )
    for name, net, (height, width) in cases:
        path = tmp_path / f"{name}.onnx"
        assert export_network(net, path, "onnx", height=height, width=width) <= 1e-4
        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        assert [d.shape for d in session.get_inputs()] == [[1, 3, height, width]] * 2
        target, captured = inputs(height, width, seed=5)
        exported = session.run(None, {"target": target.numpy(), "captured": captured.numpy()})[0]
        with torch.no_grad():
            reference = net(target, captured)
        assert np.abs(exported - reference.numpy()).max() < 1e-4
        assert (reference - target).abs().max() > 1e-2  # the network does something


def weight_only_nodes(model) -> list[str]:
    """Nodes whose inputs are all constants (initializers, ``Constant`` nodes and what is computed from
    them), other than the shape fills left unfolded (``UNFOLDED_OPERATORS``) and nodes on their outputs."""
    from edofproj.compensation.export import UNFOLDED_OPERATORS

    constant = {i.name for i in model.graph.initializer}
    fills: set[str] = set()
    found = []
    for node in model.graph.node:
        inputs = [name for name in node.input if name]
        if node.op_type == "Constant" or all(name in constant for name in inputs):
            constant.update(node.output)
            if node.op_type in UNFOLDED_OPERATORS or any(name in fills for name in inputs):
                fills.update(node.output)
            elif node.op_type != "Constant":
                found.append(f"{node.op_type} {node.name}")
    return found


def graph_facts(path):
    """``(operator counts, weight-only nodes, double-precision tensors, MatMuls without a constant operand)``."""
    import collections

    import onnx

    model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    double = onnx.TensorProto.DOUBLE
    doubles = [i.name for i in model.graph.initializer if i.data_type == double]
    doubles += [v.name for v in model.graph.value_info if v.type.tensor_type.elem_type == double]
    doubles += [n.name for n in model.graph.node if n.op_type == "Cast" and n.attribute[0].i == double]
    constants = {i.name for i in model.graph.initializer}
    variable_matmuls = [n.name for n in model.graph.node if n.op_type == "MatMul" and not set(n.input) & constants]
    operators = collections.Counter(n.op_type for n in model.graph.node)
    return operators, weight_only_nodes(model), doubles, variable_matmuls


def test_fourier_exports_are_float32_matrix_products_with_the_weights_folded(tmp_path):
    """The FFTs of every fixed-size export (radial filter, linear base filter, display guard) are
    float32 matrix products, not DFT nodes; nothing is computed from the weights alone (transfer
    functions are constants); each matrix product applies a constant matrix to the frame. The guard's
    linear filter is the network's, and its projections share one forward transform."""
    pytest.importorskip("onnxscript")
    from edofproj.compensation.multirate import MultirateCompensationNet
    from edofproj.methods.guard import GuardedNetwork
    from synthetic_psfs import gaussian_psfs

    torch.manual_seed(4)
    prefiltered = CompensationUNet([4, 8], prefilter_bins=8).eval()
    torch.nn.init.normal_(prefiltered.prefilter.gain, std=0.1)
    safe = CompensationUNet([4, 8], linear_radius=6, correction_bound=0.2, correction_highpass_px=4.0)
    safe.linear_base.set_from_psfs(gaussian_psfs([0.8, 1.5, 2.5]), 0.01)
    torch.nn.init.normal_(safe.head.weight, std=0.3)
    guarded = GuardedNetwork(safe.eval(), gaussian_psfs([0.8, 2.0, 3.5]))
    multirate = MultirateCompensationNet([4, 8], filter_bins=8).eval()
    for name, net in (("prefiltered", prefiltered), ("safe", safe), ("guarded", guarded), ("multirate", multirate)):
        path = tmp_path / f"{name}.onnx"
        assert export_network(net, path, "onnx", height=37, width=50) <= 1e-4  # odd: padded blocks
        operators, weight_only, doubles, variable_matmuls = graph_facts(path)
        assert "DFT" not in operators and operators["MatMul"] >= 8, name
        assert weight_only == [], name
        assert doubles == [], name
        assert variable_matmuls == [], name
        if name == "guarded":  # 8 for the linear filter, 4 for the forward transform, 4 per guard depth
            assert operators["MatMul"] == 8 + 4 + 4 * 3


def test_fourier_filter_onnx_export_names_the_missing_package(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxscript", None)
    net = CompensationUNet([4, 8], prefilter_bins=8).eval()
    with pytest.raises(EdofprojError, match=r"needs onnxscript .*edofproj\[export\]"):
        export_network(net, tmp_path / "net.onnx", "onnx", height=32, width=40)
    assert not (tmp_path / "net.onnx").exists()


def test_onlineprodeb_exports_to_onnx(tmp_path):
    torch.manual_seed(0)
    net = OnlineProDebNet.from_preset("fast").eval()
    torch.nn.init.normal_(net.generator.tail.weight, std=0.2)
    assert export_network(net, tmp_path / "opd.onnx", "onnx", height=32, width=32) < 1e-4


class SizeDependent(torch.nn.Module):
    """A Python branch on the frame size: a trace freezes it, so other sizes come out wrong."""

    def forward(self, target, captured):
        if target.shape[-1] > 40:
            return target + 2.0 * captured
        return target - captured


def test_failed_verification_writes_nothing(tmp_path):
    path = tmp_path / "bad.onnx"
    with pytest.raises(EdofprojError, match="differs from PyTorch.*nothing written"):
        export_network(SizeDependent(), path, "onnx", height=48, width=64)
    assert list(tmp_path.iterdir()) == []


def test_missing_onnx_names_the_packages(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(EdofprojError, match=r"needs onnx.*edofproj\[export\]"):
        export_network(small_unet(), tmp_path / "net.onnx", "onnx")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def trained_run(tmp_path):
    """A run directory as the trainer writes it: config.yaml + checkpoints/last.pt."""
    from edofproj.compensation.registry import build_network
    from edofproj.config import Config
    from edofproj.runs import CHECKPOINT_DIR, write_run_config
    from edofproj.runs.checkpoint import save_checkpoint

    cfg = Config()
    cfg.doe.kind = "lens"
    cfg.net.widths = [4, 8, 16]
    run_dir = tmp_path / "run"
    write_run_config(run_dir, cfg.validate())
    torch.manual_seed(3)
    net = build_network(cfg.net)
    torch.nn.init.normal_(net.head.weight, std=0.3)
    save_checkpoint(run_dir / CHECKPOINT_DIR, {"step": 5, "net": net.state_dict(), "doe": {}})
    return run_dir, net.eval()


def test_cli_exports_a_run(trained_run, capsys):
    run_dir, net = trained_run
    assert main(["export", str(run_dir), "--format", "onnx", "--height", "32", "--width", "48"]) == 0
    printed = capsys.readouterr().out
    assert "net.onnx" in printed and "step 5" in printed
    session = onnxruntime.InferenceSession(str(run_dir / "net.onnx"), providers=["CPUExecutionProvider"])
    target, captured = inputs(40, 40)
    out = session.run(None, {"target": target.numpy(), "captured": captured.numpy()})[0]
    with torch.no_grad():
        assert np.abs(out - net(target, captured).numpy()).max() < 1e-4
    out_file = run_dir / "exported" / "net.pt"
    assert (
        main(
            [
                "export",
                str(run_dir),
                "--format",
                "torchscript",
                "--out",
                str(out_file),
                "--height",
                "32",
                "--width",
                "32",
            ]
        )
        == 0
    )
    assert out_file.is_file()


def test_cli_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["export", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a training run" in err
    assert main(["export", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err
    with pytest.raises(SystemExit) as exit_info:
        main(["export", str(tmp_path / "empty"), "--format", "tflite"])
    assert exit_info.value.code == 2


def test_a_guarded_export_stores_no_transfer_function_per_pixel(tmp_path):
    """The file does not grow with the frame's area: exported at 64x96 and at 192x288 (9x the pixels),
    the two files differ by less than 8/9 of one transfer function on the larger frame's FFT grid
    (what storing any per-pixel transfer function at both sizes would add). Both match PyTorch; the
    larger is decided on the guard's tiles."""
    pytest.importorskip("onnxscript")
    from edofproj.imaging.convolution import fft_shape
    from edofproj.methods.guard import GuardedNetwork
    from synthetic_psfs import gaussian_psfs

    torch.manual_seed(4)
    safe = CompensationUNet([4, 8], linear_radius=6, correction_bound=0.2, correction_highpass_px=4.0)
    safe.linear_base.set_from_psfs(gaussian_psfs([0.8, 1.5, 2.5]), 0.01)
    torch.nn.init.normal_(safe.head.weight, std=0.3)
    guarded = GuardedNetwork(safe.eval(), gaussian_psfs([0.8, 2.0, 3.5]))
    assert guarded.tiles_for(64, 96) == [] and len(guarded.tiles_for(192, 288)) >= 1
    sizes = []
    for height, width in ((64, 96), (192, 288)):
        path = tmp_path / f"guarded_{height}x{width}.onnx"
        assert export_network(guarded, path, "onnx", height=height, width=width) <= 1e-4
        sizes.append(path.stat().st_size)
    rows, cols = fft_shape((192 + 12, 288 + 12), (13, 13))  # the linear filter's: reflect-padded by its radius
    one_transfer_function = 4 * 3 * 2 * cols * (rows // 2 + 1)  # float32, 3 colours, complex half spectrum
    assert sizes[1] - sizes[0] < one_transfer_function * 8 / 9, (sizes, one_transfer_function)


def _guarded_test_network():
    """A small safe U-Net (random head, so its correction is not negligible) behind its display guard."""
    from edofproj.methods import guard
    from synthetic_psfs import gaussian_psfs

    torch.manual_seed(4)
    safe = CompensationUNet([4, 8], linear_radius=6, correction_bound=0.2, correction_highpass_px=4.0)
    safe.linear_base.set_from_psfs(gaussian_psfs([0.8, 1.5, 2.5]), 0.01)
    torch.nn.init.normal_(safe.head.weight, std=0.3)
    return guard.GuardedNetwork(safe.eval(), gaussian_psfs([0.8, 2.0, 3.5]))


def test_a_guarded_export_decides_on_the_whole_frame_only_in_a_branch(tmp_path, monkeypatch):
    """The whole frame's decision is the ``then`` graph of an ``If`` node (ONNX Runtime runs it only where
    the tiled margin is near a tie), not a computation of every frame: the main graph holds no SSIM
    filter of the whole frame. With the band at 1 (every frame decided whole) and at 0 (never), the
    file's output equals the guarded module's on frames it was not verified on."""
    pytest.importorskip("onnxscript")
    import onnx

    from edofproj.methods import guard

    guarded = _guarded_test_network()
    height, width = 192, 288
    assert len(guarded.tiles_for(height, width)) >= 1
    for band in (1.0, 0.0):
        monkeypatch.setattr(guard, "GUARD_MARGIN_BAND", band)
        path = tmp_path / f"guarded_{band}.onnx"
        assert export_network(guarded, path, "onnx", height=height, width=width) <= 1e-4
        graph = onnx.load(str(path)).graph
        (branch,) = [node for node in graph.node if node.op_type == "If"]
        then_graph = next(a.g for a in branch.attribute if a.name == "then_branch")
        side = height - 2 * 5  # the SSIM map's rows (11-px Gaussian window)
        whole_frame_filters = [n for n in then_graph.node if n.op_type == "Conv"]
        assert whole_frame_filters, "the whole frame's SSIM filter is in the branch"
        shapes = onnx.shape_inference.infer_shapes(onnx.load(str(path))).graph.value_info
        assert not [
            v.name for v in shapes if [d.dim_value for d in v.type.tensor_type.shape.dim][-2:] == [side, width - 10]
        ]
        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        for seed in (11, 12):
            target, captured = inputs(height, width, seed)
            with torch.no_grad():
                reference = guarded(target, captured)
            exported = session.run(None, {"target": target.numpy(), "captured": captured.numpy()})[0]
            assert np.abs(exported - reference.numpy()).max() < 1e-4


def test_a_wrong_branch_the_frame_does_not_take_is_refused(tmp_path, monkeypatch):
    """The verification runs both branches of a guarded file on its frame: with the band at 0 the frame
    is decided on tiles, and a file whose whole-frame branch returns the negated margin (the opposite
    decision) is refused with a one-line error naming that branch, and nothing is written."""
    pytest.importorskip("onnxscript")
    import onnx

    from edofproj.compensation import export
    from edofproj.methods import guard

    guarded = _guarded_test_network()
    monkeypatch.setattr(guard, "GUARD_MARGIN_BAND", 0.0)
    joined = export._conditional_model

    def negated_branch(parts, height, width):
        model = joined(parts, height, width)
        (branch,) = [node for node in model.graph.node if node.op_type == "If"]
        then_graph = next(a.g for a in branch.attribute if a.name == "then_branch")
        result = then_graph.output[0].name
        then_graph.node.append(onnx.helper.make_node("Neg", [result], [result + "_negated"]))
        then_graph.output[0].name = result + "_negated"
        return model

    monkeypatch.setattr(export, "_conditional_model", negated_branch)
    path = tmp_path / "guarded.onnx"
    with pytest.raises(EdofprojError, match="the branch the frame does not take") as error:
        export_network(guarded, path, "onnx", height=192, width=288)
    assert "\n" not in str(error.value)
    assert not path.exists() and list(tmp_path.iterdir()) == []
