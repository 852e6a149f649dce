"""The CUDA path agrees with the CPU path: PSF engines, image formation, compensation, networks,
training steps, resume, evaluation, mixed precision and CUDA-graph timing.

Every test here needs a CUDA GPU and is skipped without one (the reason says so). Each compares
the GPU's result with the same computation on the CPU, an independent implementation as far as
the kernels go (cuFFT/cuDNN/cuBLAS against pocketfft/oneDNN/MKL): float64 work must agree to
about 1e-10, float32 work to float32 rounding (TF32 is turned off by ``float32_matmul``).

Device placement itself (a tensor made on the CPU, a CPU generator, float64 in float32 work) is
checked without a GPU by ``tests/test_device_placement.py``, which ``benchmarks/gpu/run_gpu_checks.sh``
runs first: a failure here is then a numerical difference of CUDA, or CUDA's own API.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from devices import cuda_only
from edofproj.config import Config, apply_overrides, load_config
from edofproj.doe import build_doe
from edofproj.imaging.depth_layers import layer_depths_m, render_depth_map
from edofproj.imaging.projection import project
from edofproj.imaging.screens import tilted_plane_depth_map
from edofproj.optics.psf_bank import simulator_from_config
from tiny_configs import TINY_EVALUATION, TINY_TRAINING

pytestmark = cuda_only

DEPTHS_M = [0.3, 0.5, 0.8]


def _mlp_doe(cfg: Config, seed: int = 3):
    """The config's MLP DOE with random (non-trivial) weights."""
    torch.manual_seed(seed)
    doe = build_doe(cfg, "mlp")
    with torch.no_grad():
        for p in doe.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return doe


def _relative(a: torch.Tensor, b: torch.Tensor) -> float:
    """``||a - b|| / ||b||`` with both on the CPU in float64."""
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    return float((a - b).norm() / b.norm())


# ----------------------------------------------------------------------------- optics


@pytest.mark.parametrize("engine,kind,pupil_samples", [("radial", "mlp", 384), ("2d", "cubic", 512)])
def test_psf_engines_agree_with_the_cpu_in_float64(engine, kind, pupil_samples):
    # the cubic plate's phase needs >= 480 pupil samples (its sampling rule refuses 384)
    cfg = apply_overrides(Config(), TINY_TRAINING + [f"psf.engine={engine}", f"psf.pupil_samples={pupil_samples}"])
    doe = _mlp_doe(cfg) if kind == "mlp" else build_doe(cfg, kind)
    psf = {}
    for device in ("cpu", "cuda"):
        simulator = simulator_from_config(cfg, engine=engine, device=device)
        with torch.no_grad():
            psf[device] = simulator(doe.to(device), DEPTHS_M)
    assert psf["cuda"].device.type == "cuda" and psf["cuda"].dtype == torch.float64
    assert _relative(psf["cuda"], psf["cpu"]) < 1e-10
    assert float(psf["cpu"].sum(dim=(-1, -2)).min()) > 0.5  # real PSFs, most energy in the window


def test_psf_gradient_wrt_the_doe_agrees_with_the_cpu():
    cfg = apply_overrides(Config(), TINY_TRAINING + ["psf.pupil_samples=384"])
    grads = {}
    for device in ("cpu", "cuda"):
        doe = _mlp_doe(cfg).to(device)
        simulator = simulator_from_config(cfg, device=device)
        psf = simulator(doe, DEPTHS_M)
        weights = torch.linspace(0, 1, psf.shape[-1], dtype=psf.dtype, device=device)
        (psf * weights).sum().backward()  # a functional that depends on the PSF's shape
        grads[device] = torch.cat([p.grad.reshape(-1) for p in doe.parameters() if p.grad is not None])
    assert float(grads["cpu"].abs().max()) > 0
    # the PSF is float64, the MLP's weights and their gradients float32 (a few float32 roundings,
    # 1.7e-7 on an H100): the float64 PSFs' 1e-10 does not carry over to the MLP's backward pass
    assert all(p.dtype == torch.float32 for p in doe.parameters())
    assert _relative(grads["cuda"], grads["cpu"]) < 1e-6


# ----------------------------------------------------------------------------- image formation


def _random_psf(generator: torch.Generator, batch: int = 2, window: int = 15) -> torch.Tensor:
    psf = torch.rand(batch, 3, window, window, generator=generator)
    return 0.9 * psf / psf.sum(dim=(-1, -2), keepdim=True)  # 10 % haze


def test_projection_and_depth_layers_agree_with_the_cpu():
    generator = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 40, 56, generator=generator)
    psf = _random_psf(generator)
    flat = project(image.cuda(), psf.cuda())
    assert flat.device.type == "cuda"
    torch.testing.assert_close(flat.cpu(), project(image, psf), rtol=0, atol=2e-6)

    depth_map = tilted_plane_depth_map(40, 56, 40.0, 0.5, 0.8)
    layers = layer_depths_m(0.5, 0.8, 3)
    layer_psf = _random_psf(generator, batch=3)
    tilted = render_depth_map(image.cuda(), depth_map, layer_psf.cuda(), layers=layers)
    torch.testing.assert_close(
        tilted.cpu(), render_depth_map(image, depth_map, layer_psf, layers=layers), rtol=0, atol=2e-6
    )


def test_wiener_and_constrained_least_squares_agree_with_the_cpu():
    from edofproj.compensation.constrained import box_constrained_deconvolution
    from edofproj.compensation.wiener import TorchWienerCompensator, wiener_deconvolve

    generator = torch.Generator().manual_seed(1)
    image = torch.rand(1, 3, 48, 64, generator=generator)
    psf = _random_psf(generator, batch=1)
    torch.testing.assert_close(
        wiener_deconvolve(image.cuda(), psf.cuda(), 1e-2).cpu(), wiener_deconvolve(image, psf, 1e-2), rtol=0, atol=1e-5
    )
    cached = TorchWienerCompensator(psf[0].numpy(), 1e-2)
    torch.testing.assert_close(cached(image.cuda()).cpu(), cached(image), rtol=0, atol=1e-5)
    cls_gpu = box_constrained_deconvolution(image.cuda(), psf.cuda(), iterations=20)
    torch.testing.assert_close(
        cls_gpu.cpu(), box_constrained_deconvolution(image, psf, iterations=20), rtol=0, atol=1e-4
    )


# ----------------------------------------------------------------------------- networks


def _networks():
    from edofproj.compensation.multirate import MultirateCompensationNet
    from edofproj.compensation.onlineprodeb import OnlineProDebNet
    from edofproj.compensation.unet import CompensationUNet

    return {
        "unet": lambda: CompensationUNet([8, 16, 16]),
        "unet+prefilter": lambda: CompensationUNet([8, 16, 16], prefilter_bins=12),
        "multirate": lambda: MultirateCompensationNet([8, 16], block=4, filter_bins=12),
        "onlineprodeb": lambda: OnlineProDebNet.from_preset("default"),
    }


def _randomized(factory, seed: int = 0) -> torch.nn.Module:
    """A network with every parameter drawn at random (an untrained network is the identity)."""
    torch.manual_seed(seed)
    net = factory()
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(
                0.2 * torch.randn_like(p) / max(1.0, p[0].numel() ** 0.5) if p.dim() > 1 else 0.05 * torch.randn_like(p)
            )
    return net


@pytest.mark.parametrize("name", list(_networks()))
def test_networks_forward_and_backward_agree_with_the_cpu(name, float32_matmul):
    factory = _networks()[name]
    generator = torch.Generator().manual_seed(2)
    target = torch.rand(2, 3, 52, 68, generator=generator)
    captured = torch.rand(2, 3, 52, 68, generator=generator)
    outputs, grads = {}, {}
    for device in ("cpu", "cuda"):
        net = _randomized(factory).to(device)
        out = net(target.to(device), captured.to(device))
        (out**2).mean().backward()
        outputs[device] = out.detach()
        grads[device] = torch.cat([p.grad.reshape(-1) for p in net.parameters() if p.grad is not None])
    residual = outputs["cpu"] - target
    assert float(residual.abs().max()) > 1e-3  # the random network changes the image
    assert _relative(outputs["cuda"] - target.cuda(), residual) < 1e-4
    assert _relative(grads["cuda"], grads["cpu"]) < 1e-3


def test_cuda_graph_replays_give_the_eager_output():
    from edofproj.evaluation import timing

    net = _randomized(_networks()["unet+prefilter"])
    eager = timing.network_torch_case(net, "unet", "cuda")
    graph = timing.cuda_graph_case(eager)
    assert graph.backend == "torch+graph"
    replay = graph.build(64, 96)
    frame = eager.build(64, 96)
    with torch.inference_mode():
        expected = frame().clone()
    torch.testing.assert_close(replay(), expected, rtol=0, atol=1e-5)
    times = timing.measure_cuda_ms(replay, repeats=5, warmup=1)
    assert len(times) == 5 and all(t > 0 for t in times)


def test_a_cuda_graph_refuses_a_cpu_case():
    from edofproj.errors import EdofprojError
    from edofproj.evaluation import timing

    with pytest.raises(EdofprojError, match="CUDA graph"):
        timing.cuda_graph_case(timing.network_torch_case(_networks()["unet"](), "unet", "cpu"))


# ----------------------------------------------------------------------------- training


TRAIN = TINY_TRAINING + ["train.batch_size=2", "train.steps=4", "train.checkpoint_every=2", "train.noise_sigma=0.01"]


def _train(tmp_path, name: str, *extra: str, stop_after=None, resume=False):
    from edofproj.training.trainer import train

    cfg = apply_overrides(Config(), TRAIN + list(extra))
    return train(cfg, tmp_path / name, resume=resume, stop_after=stop_after, progress=False)


def _losses(run_dir) -> np.ndarray:
    with open(run_dir / "train_log.csv") as handle:
        return np.array([float(line.split(",")[1]) for line in handle.readlines()[1:]])


def test_a_cuda_training_run_follows_the_cpu_run(tmp_path, float32_matmul):
    from edofproj.runs.checkpoint import load_checkpoint

    gpu = _train(tmp_path, "cuda", "train.device=cuda")
    _train(tmp_path, "cpu", "train.device=cpu")
    assert gpu.peak_gpu_memory_bytes and gpu.peak_gpu_memory_bytes > 0
    np.testing.assert_allclose(_losses(tmp_path / "cuda"), _losses(tmp_path / "cpu"), rtol=1e-4)
    a = load_checkpoint(tmp_path / "cuda" / "checkpoints" / "last.pt")
    b = load_checkpoint(tmp_path / "cpu" / "checkpoints" / "last.pt")
    for key, value in b["net"].items():
        assert a["net"][key].device.type == "cpu"  # checkpoints load onto the CPU
        torch.testing.assert_close(a["net"][key], value, rtol=0, atol=1e-4)
    # The DOE MLP's output bias is a global phase: its gradient is ~0 and Adam turns rounding
    # noise in it into steps of a few percent of lr (see test_training_ddp). The rest agrees.
    output_bias = f"mlp.{2 * Config().doe.mlp_layers}.bias"
    for key, value in b["doe"].items():
        if key != output_bias:
            torch.testing.assert_close(a["doe"][key], value, rtol=0, atol=1e-4)


def test_a_cuda_run_resumes_where_it_stopped(tmp_path):
    from edofproj.runs.checkpoint import load_checkpoint

    _train(tmp_path, "straight", "train.device=cuda")
    _train(tmp_path, "chunked", "train.device=cuda", stop_after=2)
    resumed = _train(tmp_path, "chunked", "train.device=cuda", resume=True)
    assert (resumed.start_step, resumed.step) == (2, 4)
    np.testing.assert_allclose(_losses(tmp_path / "chunked"), _losses(tmp_path / "straight"), rtol=1e-5)
    a = load_checkpoint(tmp_path / "chunked" / "checkpoints" / "last.pt")
    b = load_checkpoint(tmp_path / "straight" / "checkpoints" / "last.pt")
    for key, value in b["net"].items():
        torch.testing.assert_close(a["net"][key], value, rtol=0, atol=1e-5)


def test_a_cuda_trained_run_loads_and_compensates_on_the_cpu(tmp_path, float32_matmul):
    from edofproj.runs import load_run

    _train(tmp_path, "cuda", "train.device=cuda")
    run = load_run(tmp_path / "cuda")
    generator = torch.Generator().manual_seed(4)
    target, captured = torch.rand(2, 1, 3, 32, 40, generator=generator)
    net = run.net.eval()
    with torch.no_grad():
        on_cpu = net(target, captured)
        on_gpu = net.cuda()(target.cuda(), captured.cuda()).cpu()
    torch.testing.assert_close(on_gpu, on_cpu, rtol=0, atol=1e-5)


def test_bf16_mixed_precision_trains_close_to_float32(tmp_path):
    _train(tmp_path, "fp32", "train.device=cuda", "net.prefilter_bins=8")
    mixed = _train(tmp_path, "bf16", "train.device=cuda", "net.prefilter_bins=8", "train.mixed_precision=bf16")
    assert np.isfinite(mixed.loss)
    np.testing.assert_allclose(_losses(tmp_path / "bf16"), _losses(tmp_path / "fp32"), rtol=0.02)


def test_bf16_autocast_runs_the_fourier_filter_in_float32():
    from edofproj.compensation.radial_filter import RadialFourierFilter

    fourier = RadialFourierFilter(bins=8, margin_px=4).cuda()
    with torch.no_grad():
        fourier.gain.normal_(0, 1)
    image = torch.rand(1, 3, 30, 42, device="cuda")
    with torch.autocast("cuda", dtype=torch.bfloat16):
        filtered = fourier(image)
        half_input = fourier(image.bfloat16())
    assert filtered.dtype == torch.float32
    torch.testing.assert_close(filtered, fourier(image), rtol=0, atol=1e-6)
    assert half_input.dtype == torch.bfloat16


# ----------------------------------------------------------------------------- evaluation


EVALUATION = TINY_EVALUATION + ["net.prefilter_bins=8", "train.device=cpu"]


def test_evaluation_on_cuda_scores_as_on_the_cpu(tmp_path, float32_matmul):
    from edofproj.evaluation.pipeline import evaluate_run
    from edofproj.training.trainer import train

    train(load_config(None, EVALUATION), tmp_path / "doe_net", progress=False)
    methods = ["lens", "lens+wiener", "lens+cls", "doe", "doe+wiener", "doe+net"]
    cpu = evaluate_run(tmp_path / "doe_net", tmp_path / "ev_cpu", methods=methods, device="cpu")
    gpu = evaluate_run(tmp_path / "doe_net", tmp_path / "ev_gpu", methods=methods, device="cuda")
    assert len(gpu.table.rows) == len(cpu.table.rows) == len(methods) * 2 * 2
    for a, b in zip(gpu.table.rows + gpu.tilted.rows, cpu.table.rows + cpu.tilted.rows):
        assert (a["method"], a["image"]) == (b["method"], b["image"])
        assert abs(a["psnr"] - b["psnr"]) < 1e-3
        # float32 images: SSIM's local variances E[x^2] - E[x]^2 cancel, so rounding that moves
        # PSNR by < 1e-3 dB moves SSIM by ~1e-5 (1.2e-5 seen on an H100)
        assert abs(a["ssim"] - b["ssim"]) < 1e-4
    assert cpu.nsr == pytest.approx(gpu.nsr)
