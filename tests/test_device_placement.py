"""Every tensor on the device of its inputs, in the dtype of its inputs: checked on the CPU, before a GPU.

Each component runs with its inputs and parameters on a second device, PyTorch's ``meta`` device
with the values kept on the CPU (:mod:`meta_device`): an operator that meets a tensor made on the
CPU (a missing ``device=``), a CPU generator drawing onto the device, or (where forbidden) a float64
tensor inside float32 work fails here with the op and the line, as it would fail on a CUDA GPU. Each
result must also equal the plain CPU run, so the check runs the real computation, reads included.

Covered: both PSF engines through the simulator (values and DOE gradients, float64 and float32),
image formation (flat screen, depth layers, field-varying PSFs, textured surfaces), the networks
(forward and backward, float32 only and no read back to the host), training steps (joint, fixed
DOE, safe network with validation, depth-varying screens, textured surfaces, a resumed session and
a whole ``train`` call with its checkpoint, DOE file and figures), the evaluated methods and the
display guard, their NSR tuning and the timing cases, the live loop's frame maps (``live
--device``); the whole ``evaluate`` (flat, tilted, scenes, surfaces) in the slow tier. A GPU session runs this file first (``benchmarks/gpu/run_gpu_checks.sh``).
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest
import torch

from edofproj.compensation.linear_base import LinearBase
from edofproj.compensation.multirate import MultirateCompensationNet
from edofproj.compensation.onlineprodeb import OnlineProDebNet
from edofproj.compensation.surface_net import SurfaceAwareNet
from edofproj.compensation.unet import CompensationUNet
from edofproj.config import Config, apply_overrides, load_config
from edofproj.doe import build_doe, load_doe, save_doe
from edofproj.doe.base import DOE
from edofproj.errors import BlurExceedsWindowWarning, SpectralSamplingWarning
from edofproj.evaluation import timing
from edofproj.imaging.convolution import convolve_same
from edofproj.imaging.depth_layers import bank_layers, layer_depths_m, render_depth_map
from edofproj.imaging.field_varying import field_centres_px, project_field_varying
from edofproj.imaging.projection import ScreenProjection, project
from edofproj.imaging.screens import tilted_plane_depth_map
from edofproj.imaging.surfaces import Surface
from edofproj.methods.compensators import (
    ConstrainedCompensation,
    EnsembleWienerCompensation,
    NetworkCompensation,
    WienerCompensation,
    no_compensation,
    training_crops,
    tune_ensemble_nsr,
    tune_nsr,
)

# the compensation methods that ship, and the display guard (moving to edofproj.methods)
from edofproj.methods.designs import OpticalDesign
from edofproj.methods.guard import GuardedNetworkCompensation
from edofproj.optics.psf_bank import PSFBank, simulator_from_config
from edofproj.reporting.psf_plots import plot_psf_comparison
from edofproj.runs.figures import plot_doe_profile
from edofproj.training.distributed import ProcessGroup
from edofproj.training.trainer import _Session
from meta_device import META, DeviceMismatch, MetaDevice
from synthetic_psfs import gaussian_psfs
from tiny_configs import TINY_EVALUATION, TINY_TRAINING

F64 = frozenset({torch.float64, torch.complex128})
F32 = frozenset({torch.float32, torch.complex64})
DEPTHS_M = [0.4, 0.7]

pytestmark = pytest.mark.filterwarnings(
    f"ignore::{SpectralSamplingWarning.__module__}.{SpectralSamplingWarning.__name__}",
    f"ignore::{BlurExceedsWindowWarning.__module__}.{BlurExceedsWindowWarning.__name__}",
    # load_state_dict warns that a copy into a meta parameter does nothing; MetaDevice copies the values
    "ignore:.*copying from a non-meta parameter:UserWarning",
)


def _meta(x):
    """A tensor or module moved to the meta device (inside :class:`MetaDevice`)."""
    return x.to(META)


def _rand(*shape: int, seed: int = 0, dtype=torch.float32) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def _random_psfs(count: int, window: int = 9, seed: int = 1, dtype=torch.float32) -> torch.Tensor:
    psf = _rand(count, 3, window, window, seed=seed, dtype=dtype)
    return 0.9 * psf / psf.sum(dim=(-1, -2), keepdim=True)  # 10 % haze


def _randomized(net: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Every parameter drawn at random (an untrained network is the identity: nothing to compare)."""
    torch.manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            scale = 0.2 / max(1.0, p[0].numel() ** 0.5) if p.dim() > 1 else 0.05
            p.copy_(scale * torch.randn_like(p))
    return net


# ----------------------------------------------------------------------------- the check itself


def test_the_check_fails_where_a_gpu_would():
    image = _rand(1, 3, 8, 8)
    with MetaDevice() as device:
        x = _meta(image)
        with pytest.raises(DeviceMismatch, match="mixes devices"):
            x * torch.ones(8)  # made without device=
        with pytest.raises(DeviceMismatch, match="mixes devices"):  # PyTorch's meta kernel lets this pass
            torch.nn.functional.conv2d(x, torch.ones(2, 3, 3, 3))
        with pytest.raises(DeviceMismatch, match="cpu generator"):
            torch.rand(3, device=x.device, generator=torch.Generator().manual_seed(0))
        with pytest.raises(TypeError, match="meta"):
            x.numpy()  # .cpu() first, as on a GPU
        y = x * torch.tensor(2.0) + torch.tensor([1.0], device=x.device)  # a CPU scalar is allowed, as on CUDA
        assert y.device.type == "meta"
        torch.testing.assert_close(device.data(y), image * 2 + 1)
        assert float(y.max()) == pytest.approx(float((image * 2 + 1).max()))  # a read back to the host
        assert sum(device.host_reads.values()) == 1
    with MetaDevice(forbid_dtypes=F64):
        with pytest.raises(DeviceMismatch, match="float64"):
            _meta(image) * torch.tensor(np.ones(8), device=META)  # a float64 constant in float32 work


# ----------------------------------------------------------------------------- PSF engines


def _design(cfg, kind: str, tmp_path) -> DOE | None:
    """The config's design ``kind`` with random parameters; ``file``: an MLP design saved and loaded."""
    torch.manual_seed(3)
    doe = build_doe(cfg, "mlp" if kind == "file" else kind)
    with torch.no_grad():
        for p in doe.parameters():
            p.add_(0.3 * torch.randn_like(p))
    if kind == "file":
        save_doe(doe, tmp_path / "doe.npz", samples=cfg.psf.pupil_samples)
        return load_doe(tmp_path / "doe.npz")
    return doe


RADIAL = [("radial", kind, extra, precision) for precision in ("float64", "float32") for kind, extra in (
    ("lens", []), ("mlp", []), ("multifocal", []), ("file", []), ("mlp", ["optics.zernike_um={11: 0.05}"])
)]  # fmt: skip
#: the 2-D engine at one wavelength (its loop over wavelengths is the same for three)
FOURIER = [
    ("2d", "cubic", ["psf.pupil_samples=480"], "float64"),
    ("2d", "mlp", ["optics.zernike_um={7: 0.05}"], "float32"),
]


@pytest.mark.parametrize("engine,kind,extra,precision", RADIAL + FOURIER)
def test_psf_engines_stay_on_the_device(engine, kind, extra, precision, tmp_path):
    cfg = apply_overrides(
        Config(),
        TINY_TRAINING + ["psf.pupil_samples=384", f"psf.engine={engine}", f"psf.precision={precision}"] + extra,
    )
    doe = _design(cfg, kind, tmp_path)
    wavelength_nm = 550.0 if engine == "2d" else None
    expected = simulator_from_config(cfg, wavelength_nm)(doe, DEPTHS_M)
    trainable = doe is not None and any(p.requires_grad for p in doe.parameters())
    if trainable:
        expected.square().sum().backward()
        grads = [p.grad.clone() for p in doe.parameters()]
        doe.zero_grad(set_to_none=True)
    with MetaDevice() as device:
        simulator = simulator_from_config(cfg, wavelength_nm, device=META)
        psf = simulator(doe if doe is None else _meta(doe), DEPTHS_M)
        assert psf.device == META and psf.dtype == expected.dtype
        torch.testing.assert_close(
            device.data(psf), expected.detach(), rtol=0, atol=1e-13 if precision == "float64" else 1e-6
        )
        if trainable:
            psf.square().sum().backward()
            for p, grad in zip(doe.parameters(), grads):
                assert p.grad.device == META
                torch.testing.assert_close(device.data(p.grad), grad, rtol=1e-6, atol=1e-9)


# ----------------------------------------------------------------------------- image formation


def _image_formation_cases(dtype):
    psf, layer_psf = _random_psfs(2, dtype=dtype), _random_psfs(3, seed=2, dtype=dtype)
    grid = _random_psfs(6, seed=3, dtype=dtype).reshape(2, 3, 3, 9, 9)
    depth_map = tilted_plane_depth_map(40, 56, 40.0, 0.5, 0.8)
    two_maps = np.stack([depth_map, depth_map[:, ::-1]])
    layers = layer_depths_m(0.5, 0.8, 3)
    bank = PSFBank(_random_psfs(4, seed=4, dtype=dtype), np.array([0.45, 0.55, 0.7, 0.85]), np.full(4, 1e-3))
    surface = Surface.from_arrays(_rand(1, 3, 40, 56, seed=5), 0.05)
    rows, cols = field_centres_px([-0.5, 0.5], 40), field_centres_px([-0.6, 0.0, 0.6], 56)
    return {
        "flat": lambda image, move: project(image, move(psf)),
        "flat, no haze": lambda image, move: project(image, move(psf), haze=False),
        "one PSF for the batch": lambda image, move: convolve_same(image, move(psf[:1])),
        "projection kept for two images": lambda image, move: (lambda screen: screen(image) + screen(image.flip(-1)))(
            ScreenProjection(move(psf))
        ),
        "depth layers": lambda image, move: render_depth_map(image, depth_map, move(layer_psf), layers=layers),
        "depth map per sample": lambda image, move: render_depth_map(image, two_maps, move(layer_psf), layers=layers),
        "depth layers, PSFs by call": lambda image, move: render_depth_map(
            image, depth_map, lambda z: move(layer_psf), layers=3
        ),
        "PSF file's layers": lambda image, move: (lambda z, p: render_depth_map(image, depth_map, move(p), layers=z))(
            *bank_layers(bank, depth_map)
        ),
        "field-varying PSFs": lambda image, move: project_field_varying(image, move(grid), rows, cols),
        "textured surface": lambda image, move: surface.to(image.device, dtype).appearance(project(image, move(psf))),
    }


@pytest.mark.parametrize("dtype,forbidden", [(torch.float32, F64), (torch.float64, F32)], ids=["float32", "float64"])
def test_image_formation_stays_on_the_device_in_the_images_dtype(dtype, forbidden):
    image = _rand(2, 3, 40, 56, seed=6, dtype=dtype) * 1.2 - 0.1
    cases = _image_formation_cases(dtype)
    for name, case in cases.items():
        expected = case(image, lambda t: t)
        with MetaDevice(forbid_dtypes=forbidden) as device:
            shown = case(_meta(image), _meta)
            assert shown.device == META and shown.dtype == dtype, name
            torch.testing.assert_close(device.data(shown), expected, rtol=0, atol=1e-6, msg=name)


# ----------------------------------------------------------------------------- networks


NETWORKS = {
    "unet": lambda: CompensationUNet([4, 8, 8]),
    "unet, blocks, maxpool, bilinear, reflect": lambda: CompensationUNet(
        [4, 8, 8], space_to_depth=2, downsampling="maxpool", upsampling="bilinear", padding_mode="reflect"
    ),
    "unet+prefilter": lambda: CompensationUNet([4, 8, 8], prefilter_bins=8),
    "safe unet": lambda: CompensationUNet([4, 8, 8], linear_radius=5),
    "multirate": lambda: MultirateCompensationNet([8, 8], block=4, filter_bins=8),
    "onlineprodeb": lambda: OnlineProDebNet.from_preset("fast"),
    "surface-aware": lambda: SurfaceAwareNet(CompensationUNet([4, 8, 8], prefilter_bins=8)),
}


@pytest.mark.parametrize("name", list(NETWORKS))
def test_networks_stay_on_the_device_in_float32_without_host_reads(name):
    target, captured = _rand(2, 3, 36, 44, seed=7), _rand(2, 3, 36, 44, seed=8)
    net = _randomized(NETWORKS[name]())
    expected = net(target, captured)
    expected.square().mean().backward()
    grads = [p.grad.clone() for p in net.parameters()]
    net.zero_grad(set_to_none=True)
    with MetaDevice(forbid_dtypes=F64) as device:
        _meta(net)
        out = net(_meta(target), _meta(captured))
        assert out.device == META and out.dtype == torch.float32
        out.square().mean().backward()
        with torch.inference_mode():
            frame = net(_meta(target), _meta(captured))
        assert not device.host_reads  # a network never waits for the GPU
    torch.testing.assert_close(device.data(out), expected.detach(), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(device.data(frame), expected.detach(), rtol=1e-5, atol=1e-6)
    for p, grad in zip(net.parameters(), grads):
        torch.testing.assert_close(device.data(p.grad), grad, rtol=1e-4, atol=1e-7)


def test_network_filters_are_set_on_the_device():
    kernels = np.random.default_rng(0).normal(scale=0.1, size=(3, 5, 5))
    psfs = gaussian_psfs([0.8, 1.5, 2.5], window=9)
    net = MultirateCompensationNet([8, 8], block=4, filter_bins=8)
    expected = copy.deepcopy(net)
    expected.initialize_linear_path(kernels)
    base, expected_base = LinearBase(3, 5), LinearBase(3, 5)
    expected_base.set_from_psfs(psfs, 0.01)
    with MetaDevice() as device:
        _meta(net).initialize_linear_path(kernels)
        _meta(base).set_from_psfs(_meta(psfs), 0.01)
        for p, q in zip(net.parameters(), expected.parameters()):
            torch.testing.assert_close(device.data(p), q.detach(), rtol=0, atol=0)
        assert base.kernel.device == META
        torch.testing.assert_close(device.data(base.kernel), expected_base.kernel, rtol=0, atol=0)


# ----------------------------------------------------------------------------- training


TRAINING = TINY_TRAINING + ["train.batch_size=2", "train.steps=4", "train.noise_sigma=0.01"]
FIXED_DOE = ["doe.kind=multifocal", "psf.pupil_samples=512", "train.psf_table_depths=4"]
SESSIONS = {
    "joint DOE and U-Net": ["net.prefilter_bins=8", "train.quantize_capture=true"],
    "fixed DOE, multirate from Wiener": FIXED_DOE
    + ["net.architecture=multirate", "net.widths=[8,8]", "net.block_px=2", "net.filter_bins=8", "net.init_nsr=0.01"],
    "safe network, validated": ["net.linear_base=ensemble", "net.linear_radius=5", "train.linear_every=2"]
    + ["train.validate_every=2", "train.validation_images=2"],
    "depth-varying screens": ["train.screens=varying", "imaging.depth_layers=2"],
    "textured surfaces, MS-SSIM": ["net.surface_input=true", "loss.perceptual=ms-ssim", "loss.beta=0.5"]
    + ["data.crop=48"],
}
#: the sessions of the fast tier (the others take seconds each: slow tier)
FAST_SESSIONS = ("joint DOE and U-Net", "fixed DOE, multirate from Wiener")


def _steps(session: _Session, count: int) -> list[tuple[float, float, float]]:
    losses = []
    for _ in range(count):
        losses.append(session.train_step())
        session.checks.after_step(session.step, say=lambda _: None)
    return losses


@pytest.mark.parametrize(
    "name", [name if name in FAST_SESSIONS else pytest.param(name, marks=pytest.mark.slow) for name in SESSIONS]
)
def test_training_steps_stay_on_the_device(name, tmp_path):
    cfg = apply_overrides(Config(), TRAINING + SESSIONS[name])
    (tmp_path / "cpu").mkdir()
    (tmp_path / "meta").mkdir()
    on_cpu = _Session(cfg, tmp_path / "cpu", ProcessGroup())
    on_cpu.checks.start(0, resumed=False)
    expected = _steps(on_cpu, 2)
    with MetaDevice() as device:
        session = _Session(cfg, tmp_path / "meta", ProcessGroup(device=META))
        session.checks.start(0, resumed=False)
        losses = _steps(session, 2)
        parameters = list(session.model.parameters())
        assert all(p.device == META for p in parameters)
    np.testing.assert_allclose(losses, expected, rtol=1e-5)
    for p, q in zip(parameters, on_cpu.model.parameters()):
        torch.testing.assert_close(device.data(p), q.detach(), rtol=1e-4, atol=1e-6)


def test_a_fixed_doe_step_makes_no_float64_on_the_device(tmp_path):
    cfg = apply_overrides(Config(), TRAINING + FIXED_DOE + ["net.prefilter_bins=8", "train.screens=varying"])
    with MetaDevice() as device:
        session = _Session(cfg, tmp_path, ProcessGroup(device=META))  # the PSF table is simulated in float64
        device.forbid_dtypes = F64
        assert np.isfinite(session.train_step()[0])


def test_a_session_resumed_on_the_device_continues_the_cpu_run(tmp_path):
    cfg = apply_overrides(Config(), TRAINING + ["net.prefilter_bins=8"])
    on_cpu = _Session(cfg, tmp_path, ProcessGroup())
    _steps(on_cpu, 2)
    checkpoint = copy.deepcopy(on_cpu.state())
    expected = on_cpu.train_step()
    with MetaDevice() as device:
        session = _Session(cfg, tmp_path, ProcessGroup(device=META))
        session.restore(copy.deepcopy(checkpoint))
        loss = session.train_step()
        parameters = list(session.model.parameters())
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    for p, q in zip(parameters, on_cpu.model.parameters()):
        torch.testing.assert_close(device.data(p), q.detach(), rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_a_training_run_on_the_device_writes_its_files_and_resumes_exactly(tmp_path, monkeypatch):
    """A whole ``train`` in two sessions: steps, checkpoints, resume, the DOE's file and figures."""
    from edofproj.runs.checkpoint import load_checkpoint
    from edofproj.training import trainer

    cfg = apply_overrides(Config(), TRAINING + ["train.steps=2", "train.checkpoint_every=1"])
    trainer.train(cfg, tmp_path / "cpu", progress=False)
    monkeypatch.setattr(trainer, "setup_process_group", lambda device: ProcessGroup(device=META))
    with MetaDevice():
        trainer.train(cfg, tmp_path / "meta", stop_after=1, progress=False)
        trainer.train(cfg, tmp_path / "meta", resume=True, progress=False)
    logs = [np.loadtxt(tmp_path / run / "train_log.csv", delimiter=",", skiprows=1)[:, 1] for run in ("meta", "cpu")]
    np.testing.assert_allclose(*logs, rtol=1e-5)
    written, expected = np.load(tmp_path / "meta" / "doe.npz"), np.load(tmp_path / "cpu" / "doe.npz")
    np.testing.assert_allclose(written["height_m"], expected["height_m"], rtol=0, atol=1e-15)
    saved, expected_state = (load_checkpoint(tmp_path / run / "checkpoints" / "last.pt") for run in ("meta", "cpu"))
    for key, value in expected_state["net"].items():
        torch.testing.assert_close(saved["net"][key], value, rtol=1e-4, atol=1e-6)
    assert (tmp_path / "meta" / "figures" / "doe_profile.png").is_file()


class _TiltedPlate(DOE):
    """A trainable 2-D design (a tilt of learned slope): the 2-D branches of the DOE's writers."""

    def __init__(self, aperture_radius_m: float) -> None:
        super().__init__(aperture_radius_m, levels=None)
        self.slope = torch.nn.Parameter(torch.tensor(1e-4, dtype=torch.float64))

    def raw_height_map_m(self, x_m, y_m):
        return self.slope * (x_m + 0.5 * y_m)


@pytest.mark.parametrize("design", ["radial MLP", "2-D plate"])
def test_a_design_on_the_device_is_written_and_plotted(design, tmp_path):
    doe = _randomized(build_doe(apply_overrides(Config(), TINY_TRAINING), "mlp")) if design == "radial MLP" else None
    doe = doe or _TiltedPlate(3.5e-3)
    key = "height_m" if doe.radially_symmetric else "height_map_m"
    save_doe(doe, tmp_path / "cpu.npz", samples=64)
    bank = PSFBank(_random_psfs(2), np.array(DEPTHS_M), np.full(2, 1e-3))
    with MetaDevice():
        _meta(doe)
        save_doe(doe, tmp_path / "meta.npz", samples=64)
        plot_doe_profile(doe, tmp_path / "profile.png", samples=64)
        plot_psf_comparison([("design", doe, bank)], tmp_path / "psfs.png")
    np.testing.assert_array_equal(np.load(tmp_path / "meta.npz")[key], np.load(tmp_path / "cpu.npz")[key])
    assert (tmp_path / "profile.png").is_file() and (tmp_path / "psfs.png").is_file()


# ----------------------------------------------------------------------------- the methods that ship


def _safe_network(psfs: torch.Tensor) -> CompensationUNet:
    net = _randomized(CompensationUNet([4, 8, 8], linear_radius=6), seed=1)
    net.linear_base.set_from_psfs(psfs, 0.01)
    return net.eval()


METHODS = {
    "none": lambda psfs, move: no_compensation,
    "wiener": lambda psfs, move: WienerCompensation(0.01),
    "cls": lambda psfs, move: ConstrainedCompensation(5),
    "ensemble": lambda psfs, move: EnsembleWienerCompensation(move(psfs), 0.01, 6),
    "net": lambda psfs, move: NetworkCompensation(move(_randomized(CompensationUNet([4, 8, 8], prefilter_bins=8)))),
    "guarded net": lambda psfs, move: GuardedNetworkCompensation(move(_safe_network(psfs)), move(psfs[:3])),
}


@pytest.mark.parametrize("name", list(METHODS))
def test_compensation_methods_stay_on_the_device(name):
    target, psfs = _rand(2, 3, 36, 44, seed=9), gaussian_psfs([0.8, 1.5, 2.5, 3.5], window=9)
    psf = psfs[1:2]

    def shown(method, target, psf):
        return project(method(target, project(target, psf), psf).clamp(0, 1), psf)

    with torch.no_grad():
        expected = shown(METHODS[name](psfs, lambda x: x), target, psf)
        with MetaDevice(forbid_dtypes=F64) as device:
            method = METHODS[name](psfs, _meta)
            display = shown(method, _meta(target), _meta(psf))
            assert display.device == META and display.dtype == torch.float32
    torch.testing.assert_close(device.data(display), expected, rtol=0, atol=1e-5)
    if name == "guarded net":
        assert method.guard.chose_filter.device.type == "cpu" and method.guard.calls == 2


@pytest.mark.slow
def test_nsr_tuning_and_designs_on_the_device():
    cfg = apply_overrides(Config(), TINY_EVALUATION)
    torch.manual_seed(0)
    doe = build_doe(cfg, "mlp")
    crops = training_crops(cfg, 2, seed=0)
    on_cpu = OpticalDesign("run", "doe", doe, cfg)
    expected = tune_nsr(on_cpu, crops, cfg), tune_ensemble_nsr(on_cpu, crops, cfg, candidates=[1e-3, 1e-2])
    with MetaDevice() as device:
        design = OpticalDesign("run", "doe", doe, cfg, device=META)
        psf = design.psf(DEPTHS_M)
        assert psf.device == META and psf.dtype == torch.float32
        tuned = (
            tune_nsr(design, _meta(crops), cfg),
            tune_ensemble_nsr(design, _meta(crops), cfg, candidates=[1e-3, 1e-2]),
        )
    torch.testing.assert_close(device.data(psf), on_cpu.psf(DEPTHS_M), rtol=0, atol=0)
    for (nsr, scores), (expected_nsr, expected_scores) in zip(tuned, expected):
        assert nsr == expected_nsr
        np.testing.assert_allclose(list(scores.values()), list(expected_scores.values()), rtol=1e-5)


def test_timing_cases_run_on_the_device():
    psf = timing.disk_psf(9)
    with MetaDevice():
        cases = [
            timing.wiener_torch_case(psf, 1e-3, "meta"),
            timing.cls_torch_case(psf, 3, "meta"),
            timing.network_torch_case(CompensationUNet([4, 8, 8], prefilter_bins=8), "unet", "meta"),
            timing.network_torch_case(MultirateCompensationNet([8, 8], block=2, filter_bins=8), "multirate", "meta"),
        ]
        for case in cases:
            assert case.build(32, 48)().device == META


# ----------------------------------------------------------------------------- the live loop's maps


@pytest.mark.parametrize("table", ["per-channel", "trilinear"])
def test_live_frame_maps_stay_on_the_device(table):
    """``live --device``'s rectification and inverse response (DeviceFrameMaps): every tensor on the
    device, float32, the values of the same maps on the CPU, and no read back to the host."""
    from edofproj.procams.color import ColorCalibration
    from edofproj.procams.device_frame_maps import DeviceFrameMaps
    from edofproj.procams.frame_maps import ChannelInverseTable, Rectifier, TrilinearInverseTable
    from edofproj.procams.geometry import CameraMap

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:12, 0:16].astype(np.float64)
    camera_map = CameraMap(
        map_x=1.9 * x + 0.3 * y + 2.2, map_y=1.7 * y + 0.1 * x + 1.6,
        homography=np.eye(3), dots_proj=np.zeros((0, 2)), dots_cam=np.zeros((0, 2)), camera_hw=(30, 40),
    )  # fmt: skip
    levels = np.linspace(0, 1, 4)
    inputs = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)
    color = ColorCalibration(np.eye(3) + 0.05, np.full(3, 0.02), inputs, inputs**2.2)
    rectifier = Rectifier(camera_map, color, rng.uniform(0.01, 0.05, (12, 16, 3)))
    inverse = (
        ChannelInverseTable(rng.uniform(size=(3, 256)))
        if table == "per-channel"
        else TrilinearInverseTable(rng.uniform(size=(5, 5, 5, 3)))
    )
    frame = rng.integers(0, 256, size=(30, 40, 3)).astype(np.uint8)
    cpu_maps = DeviceFrameMaps(rectifier, inverse, "cpu")
    expected = cpu_maps.rectify(cpu_maps.upload(frame))
    expected_u, _ = cpu_maps.to_input(expected * 0.8 + 0.1)
    with MetaDevice(forbid_dtypes=F64) as device:
        maps = DeviceFrameMaps(rectifier, inverse, META)
        rectified = maps.rectify(maps.upload(frame))
        u, finite = maps.to_input(rectified * 0.8 + 0.1)
        assert rectified.device == META and u.device == META and u.dtype == torch.float32
        assert not device.host_reads  # the loop reads `finite` once the frame is on the host
        torch.testing.assert_close(device.data(rectified), expected, rtol=0, atol=0)
        torch.testing.assert_close(device.data(u), expected_u, rtol=0, atol=0)
        assert bool(device.data(finite))


# ----------------------------------------------------------------------------- evaluate, whole


@pytest.mark.slow
def test_evaluate_on_the_device_scores_as_on_the_cpu(tmp_path):
    from edofproj.evaluation.pipeline import evaluate_run
    from edofproj.evaluation.scenes import evaluate_scenes
    from edofproj.evaluation.surfaces import evaluate_surfaces
    from edofproj.training.trainer import train

    scene_sized = ["optics.width_px=64", "optics.height_px=48", "psf.depth_min_mm=300", "psf.depth_max_mm=800"]
    train(load_config(None, TINY_EVALUATION + scene_sized + ["net.prefilter_bins=8"]), tmp_path / "run", progress=False)
    methods = ["lens+cls", "doe+wiener", "doe+ensemble", "doe+net"]
    evaluations = {
        "flat and tilted": lambda device, out: evaluate_run(tmp_path / "run", out, methods=methods, device=device),
        "scenes": lambda device, out: evaluate_scenes(
            tmp_path / "run", ["sphere_wall"], out, methods=["doe", "doe+net"], device=device
        ),
        "surfaces": lambda device, out: evaluate_surfaces(
            tmp_path / "run", ["checker"], out, ambient=0.1, device=device
        ),
    }
    for name, evaluate in evaluations.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            expected = evaluate("cpu", tmp_path / f"{name}-cpu")
            with MetaDevice():
                scored = evaluate(META, tmp_path / f"{name}-meta")
        rows = scored.table.rows + getattr(scored, "tilted", scored.table).rows
        expected_rows = expected.table.rows + getattr(expected, "tilted", expected.table).rows
        assert len(rows) == len(expected_rows) > 0, name
        for row, expected_row in zip(rows, expected_rows):
            assert row["method"] == expected_row["method"]
            assert row["psnr"] == pytest.approx(expected_row["psnr"], abs=1e-4), name
            assert row["ssim"] == pytest.approx(expected_row["ssim"], abs=1e-6), name
