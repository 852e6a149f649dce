"""What a table scores is what every command ships: one method object from ``evaluate`` to
``compensate``, ``live``, ``export`` and ``bench`` (:mod:`edofproj.methods`).

Tiny runs trained here: a safe network (``net.linear_base: ensemble``, so the display guard is part
of ``doe+net``) with its lens-only baseline beside it. For every method, the projector input that
``compensate --images`` writes is the one the evaluation computes for the same image and depth,
and the SSIM of its simulated display is the one ``evaluate`` writes into ``metrics.csv``.
"""

from __future__ import annotations

import csv

import pytest
import torch

from edofproj.cli import main
from edofproj.compensation.closed_loop import closed_loop, flat_screen
from edofproj.config import load_config
from edofproj.imaging.image_io import read_image, write_image
from edofproj.imaging.projection import project
from edofproj.methods.builder import build_method
from edofproj.methods.catalogue import METHOD_NAMES, OURS, method_spec
from edofproj.methods.guard import GuardedNetwork
from edofproj.metrics import ssim
from tiny_configs import TINY_EVALUATION

pytestmark = pytest.mark.slow  # trains tiny runs and runs whole commands

SAFE = [
    "net.linear_base=ensemble",
    "net.linear_radius=5",
    "net.correction_bound=0.2",
    "train.linear_every=2",
    "psf.pupil_samples=512",  # the axicon's phase needs 512 samples
]
#: Methods of the tiny runs (the cubic, axicon and OnlineProDeb networks have no run here; the classic
#: elements' linear baselines need none).
METHODS = (
    "lens",
    "lens+wiener",
    "lens+cls",
    "lens+net",
    "doe",
    "doe+wiener",
    "doe+cls",
    "doe+ensemble",
    "doe+net",
    "axicon",
    "axicon+ensemble",
    "multifocal+wiener",
    "multifocal+ensemble",
)
DEPTH_MM = 300.0
HW = (48, 64)  # = evaluation.image_size of TINY_EVALUATION: the evaluation's centre crop is the image itself
#: 16-bit files: half a step of quantization, plus float rounding.
QUANTIZATION = 0.5 / 65535 + 1e-6


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from edofproj.training.trainer import train

    root = tmp_path_factory.mktemp("runs")
    train(load_config(None, TINY_EVALUATION + SAFE), root / "doe_net", progress=False)
    train(load_config(None, TINY_EVALUATION + SAFE + ["doe.kind=lens"]), root / "lens_net", progress=False)
    return root


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """Two targets at the evaluation's size: a smooth image and a magenta/green colour grating (the
    content the display guard exists for)."""
    folder = tmp_path_factory.mktemp("images")
    generator = torch.Generator().manual_seed(3)
    smooth = torch.nn.functional.avg_pool2d(torch.rand(1, 3, HW[0] + 8, HW[1] + 8, generator=generator), 9, 1)[0]
    grating = torch.zeros(3, *HW)
    grating[:, :, 0::4] = grating[:, :, 1::4] = torch.tensor([1.0, 0.0, 1.0]).view(3, 1, 1)
    grating[:, :, 2::4] = grating[:, :, 3::4] = torch.tensor([0.0, 1.0, 0.0]).view(3, 1, 1)
    write_image(folder / "smooth.png", smooth.clamp(0, 1), bits=16)
    write_image(folder / "grating.png", grating, bits=16)
    return folder


@pytest.fixture(scope="module")
def evaluated(runs, images, tmp_path_factory):
    """``evaluate --images`` of every method at one depth: ``{(method, image): ssim}``."""
    out = tmp_path_factory.mktemp("evaluation")
    argv = ["evaluate", str(runs / "doe_net"), "--images", str(images), "--depths-mm", str(DEPTH_MM)]
    assert main(argv + ["--methods", ",".join(METHODS), "--out", str(out), "--quiet"]) == 0
    with open(out / "metrics.csv", newline="") as handle:
        return {(row["method"], row["image"]): float(row["ssim"]) for row in csv.DictReader(handle)}


def evaluation_input(method, target: torch.Tensor) -> torch.Tensor:
    """The projector input the flat-screen sweep computes (:mod:`edofproj.evaluation.sweep`)."""
    psf = method.design.psf([DEPTH_MM * 1e-3])
    forward = flat_screen(psf)
    with torch.inference_mode():
        loop = closed_loop(target, forward, lambda t, c: method.compensate(t, c, psf), captured=forward(target))
    return loop.emitted


@pytest.mark.parametrize("name", METHODS)
def test_compensate_writes_the_projector_input_that_evaluate_scored(runs, images, evaluated, tmp_path, name):
    out = tmp_path / "out"
    argv = ["compensate", str(runs / "doe_net"), "--images", str(images), "--depth-mm", str(DEPTH_MM)]
    assert main(argv + ["--method", name, "--out", str(out), "--bits", "16"]) == 0
    method = build_method(runs / "doe_net", name)
    psf = method.design.psf([DEPTH_MM * 1e-3])
    for image in ("smooth", "grating"):
        target = read_image(images / f"{image}.png")[None]
        shipped = read_image(out / f"{image}.png")[None]
        expected = evaluation_input(method, target)
        assert float((shipped - expected).abs().max()) <= QUANTIZATION, (name, image)
        # the display of the shipped file scores what the table says
        shown_ssim = float(ssim(project(shipped, psf), target)[0])
        assert shown_ssim == pytest.approx(evaluated[(name, f"{image}.png")], abs=2e-4), (name, image)


def test_the_default_method_is_the_runs_own_network_behind_its_guard(runs):
    method = build_method(runs / "doe_net")
    assert method.name == OURS and isinstance(method.module, GuardedNetwork)
    assert method.module.net is method.network
    # the guard is in the shipped module: on the grating it may send the filter, never a worse display
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(2, 3, *HW, generator=generator)
    with torch.inference_mode():
        shown, margin = method.module.decide(target, target)
        raw, base = method.network(target, target), method.network.linear_base(target)
    for i in range(2):
        torch.testing.assert_close(shown[i], base[i] if margin[i] < 0 else raw[i])


def test_every_catalogued_method_is_built_or_refused_in_one_line(runs, capsys):
    for name in METHOD_NAMES:
        spec = method_spec(name)
        if spec.run_dir is not None and not (runs / spec.run_dir).is_dir():
            argv = ["compensate", str(runs / "doe_net"), "--image", "x.png", "--depth-mm", "300", "--out", "y.png"]
            capsys.readouterr()
            assert main(argv + ["--method", name]) == 2
            lines = capsys.readouterr().err.strip().splitlines()
            assert len(lines) == 1 and spec.run_dir in lines[0], lines


def test_a_non_blind_method_needs_a_simulated_screen(runs, images, tmp_path, capsys):
    write_image(tmp_path / "capture.png", torch.rand(3, *HW))
    argv = ["compensate", str(runs / "doe_net"), "--image", str(images / "smooth.png")]
    capsys.readouterr()
    code = main(argv + ["--capture", str(tmp_path / "capture.png"), "--method", "doe+wiener", "--out", "p.png"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not blind" in err[0]


def test_export_writes_what_compensate_runs(runs, images, tmp_path):
    """TorchScript of the guarded network against ``compensate --image`` on a capture, within 1/255."""
    out = tmp_path / "net.pt"
    assert (
        main(
            ["export", str(runs / "doe_net"), "--format", "torchscript", "--out", str(out)]
            + ["--height", "48", "--width", "64"]
        )
        == 0
    )
    module = torch.jit.load(str(out))
    for image in ("smooth", "grating"):
        target = read_image(images / f"{image}.png")[None]
        captured = project(target, build_method(runs / "doe_net").design.psf([DEPTH_MM * 1e-3]))
        write_image(tmp_path / "capture.png", captured[0], bits=16)
        argv = ["compensate", str(runs / "doe_net"), "--image", str(images / f"{image}.png")]
        assert main(argv + ["--capture", str(tmp_path / "capture.png"), "--out", str(tmp_path / "p.png")]) == 0
        shipped = read_image(tmp_path / "p.png")[None]
        with torch.inference_mode():
            exported = module(target, read_image(tmp_path / "capture.png")[None]).clamp(0, 1)
        assert float((exported - shipped).abs().max()) <= 1 / 255 + 1e-6, image


def test_live_runs_the_method_object(runs, tmp_path, monkeypatch):
    """``live`` hands the frame loop the same module ``evaluate`` scores (the devices are replaced:
    this checks what is run, :mod:`tests.test_live` checks the loop)."""
    import edofproj.application.live as live_module
    import edofproj.commands.procams.devices as device_options
    from edofproj.procams.devices import GrabSettings
    from edofproj.procams.devices.displays import MemoryDisplay
    from virtual_rigs import delta_psf, straight_rig

    rig = straight_rig(HW, delta_psf())
    rig.ideal_calibration(levels=3).save(tmp_path / "calib.npz")
    write_image(tmp_path / "target.png", torch.rand(3, *HW))
    seen = {}

    def spy(net, *args, **kwargs):
        seen["net"], seen["device"] = net, kwargs.get("device")
        return live_module.LiveSummary()

    class NoCamera:
        spec = "none"

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    monkeypatch.setattr(live_module, "run_live", spy)
    monkeypatch.setattr(device_options, "open_devices", lambda args: (MemoryDisplay(), NoCamera(), GrabSettings()))
    argv = [
        "live",
        str(runs / "doe_net"),
        "--calib",
        str(tmp_path / "calib.npz"),
        "--image",
        str(tmp_path / "target.png"),
    ]
    assert main(argv + ["--camera", "none", "--display", "memory"]) == 0
    shipped = build_method(runs / "doe_net")
    assert isinstance(seen["net"], GuardedNetwork)
    target, captured = torch.rand(1, 3, *HW), torch.rand(1, 3, *HW)
    with torch.inference_mode():
        torch.testing.assert_close(seen["net"](target, captured), shipped.compensate(target, captured, None))
    assert main(argv + ["--camera", "none", "--display", "memory", "--method", "doe+wiener"]) == 2
    assert seen["device"] is None  # the CPU's tables by default
    # --device cuda: the module and the frame maps on the GPU, or one line where there is none
    on_gpu = main(argv + ["--camera", "none", "--display", "memory", "--device", "cuda"])
    if torch.cuda.is_available():
        assert on_gpu == 0 and seen["device"].type == "cuda"
        assert all(p.is_cuda for p in seen["net"].parameters())
    else:
        assert on_gpu == 2 and seen["device"] is None


def test_bench_times_the_shipped_method_and_its_bare_network(runs, capsys):
    argv = ["bench", "--run", str(runs / "doe_net"), "--sizes", "48x64", "--repeats", "1", "--warmup", "0"]
    assert main(argv + ["--methods", "unet", "--no-onnx"]) == 0
    out = capsys.readouterr().out
    rows = [line.split("|")[1].strip() for line in out.splitlines() if line.startswith("| doe+net")]
    assert rows == ["doe+net", "doe+net without guard"]
    assert "AVX" in out or "CPU flags unknown" in out or "no AVX2" in out


def test_the_onnx_export_of_the_guarded_network_equals_compensate(runs, images, tmp_path):
    """ONNX (one frame size: the guard's projections are FFTs) against ``compensate`` on a capture, within 1/255."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnxscript")
    import onnxruntime

    out = tmp_path / "net.onnx"
    assert main(["export", str(runs / "doe_net"), "--out", str(out), "--height", "48", "--width", "64"]) == 0
    session = onnxruntime.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    declared = {i.name for i in session.get_inputs()}
    psf = build_method(runs / "doe_net").design.psf([DEPTH_MM * 1e-3])
    for image in ("smooth", "grating"):
        target = read_image(images / f"{image}.png")[None]
        write_image(tmp_path / "capture.png", project(target, psf)[0], bits=16)
        captured = read_image(tmp_path / "capture.png")[None]
        argv = ["compensate", str(runs / "doe_net"), "--image", str(images / f"{image}.png")]
        assert main(argv + ["--capture", str(tmp_path / "capture.png"), "--out", str(tmp_path / "p.png")]) == 0
        feed = {"target": target.numpy(), "captured": captured.numpy()}
        exported = session.run(None, {k: v for k, v in feed.items() if k in declared})[0].clip(0, 1)
        shipped = read_image(tmp_path / "p.png")[None].numpy()
        assert float(abs(exported - shipped).max()) <= 1 / 255 + 1e-6, image
