"""The live loop's per-frame maps on a compute device (procams/device_frame_maps.py) against the
direct computations: rectification as bilinear sampling at the camera map, the inverse response as
its table read; and the loop run with them, against the loop on the CPU's tables. Each test runs on
the CPU and, where PyTorch sees one, on a CUDA GPU."""

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import map_coordinates

from edofproj.application.live import run_live
from edofproj.application.surface_frames import SurfaceLoop
from edofproj.errors import EdofprojError
from edofproj.procams.color import ColorCalibration, ResponseLUT
from edofproj.procams.device_frame_maps import DeviceFrameMaps
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.frame_maps import ChannelInverseTable, Rectifier, TrilinearInverseTable
from edofproj.procams.geometry import CameraMap
from test_live import HW, smooth_target
from virtual_rigs import delta_psf, exact_calibration, straight_rig

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU")),
]
MIXING = np.array([[0.8, 0.1, 0.05], [0.1, 0.7, 0.1], [0.02, 0.15, 0.9]])
LEVELS = np.round(np.linspace(0, 255, 6)) / 255


def _color() -> ColorCalibration:
    inputs = np.stack(np.meshgrid(LEVELS, LEVELS, LEVELS, indexing="ij"), -1).reshape(-1, 3)
    return ColorCalibration(MIXING, np.full(3, 0.02), inputs, inputs**2.2)


def _camera_map(H=12, W=16, Hc=30, Wc=40, outside=False) -> CameraMap:
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    shift = -3.0 if outside else 2.2  # outside: the first columns fall left of the camera frame
    return CameraMap(
        map_x=1.9 * x + 0.3 * y + shift, map_y=1.7 * y + 0.1 * x + 1.6,
        homography=np.eye(3), dots_proj=np.zeros((0, 2)), dots_cam=np.zeros((0, 2)), camera_hw=(Hc, Wc),
    )  # fmt: skip


def _bilinear_clamped(frame: np.ndarray, camera_map: CameraMap) -> np.ndarray:
    """Independent bilinear sampling (SciPy) at q(x), positions clamped to the frame ('nearest' edges)."""
    Hc, Wc = frame.shape[:2]
    rows = np.clip(camera_map.map_y, 0, Hc - 1)
    cols = np.clip(camera_map.map_x, 0, Wc - 1)
    return np.stack([map_coordinates(frame[..., c], [rows, cols], order=1) for c in range(3)], axis=-1)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
@pytest.mark.parametrize("uniform_black", [True, False])
def test_rectification_on_the_device_is_the_direct_one(device, dtype, uniform_black):
    """o = M^-1 (c(q(x)) / full_scale - c_black(q(x))) with c sampled bilinearly at the exact
    positions (no 1/32-pixel rounding, no rounding to counts): float32 rounding from the direct
    float64 computation, for counts and float frames alike, positions outside the frame clamped."""
    rng = np.random.default_rng(3)
    camera_map = _camera_map(outside=True)
    black = np.broadcast_to([0.02, 0.03, 0.01], (12, 16, 3)) if uniform_black else rng.uniform(0.01, 0.05, (12, 16, 3))
    if dtype == np.float32:
        frame, top = rng.uniform(size=(30, 40, 3)).astype(np.float32), 1.0
    else:
        top = float(np.iinfo(dtype).max)
        frame = rng.integers(0, int(top) + 1, size=(30, 40, 3)).astype(dtype)
    unit = frame.astype(np.float64) / top
    direct = (_bilinear_clamped(unit, camera_map) - black) @ np.linalg.inv(MIXING).T
    maps = DeviceFrameMaps(Rectifier(camera_map, _color(), black), ChannelInverseTable(np.ones((3, 4))), device)
    rectified = maps.rectify(maps.upload(frame))
    assert rectified.shape == (1, 3, 12, 16) and rectified.dtype == torch.float32
    assert rectified.device.type == device
    # float32: the normalized grid and its unnormalization round the position by ~1e-5 pixel
    np.testing.assert_allclose(rectified[0].permute(1, 2, 0).cpu().numpy(), direct, atol=1e-5)
    with pytest.raises(EdofprojError, match="is 12x16 pixels, the calibrated camera 30x40"):
        maps.upload(frame[:12, :16])


@pytest.mark.parametrize("device", DEVICES)
def test_channel_table_on_the_device_reads_the_nearest_bin(device):
    """u_c = T_c[round(clip(o_c, 0, 1) (N - 1))], as NumPy reads the table, and as the CPU's table
    applies it (the same bins: both round half to even)."""
    table = ChannelInverseTable(np.random.default_rng(5).uniform(size=(3, 1000)))
    maps = DeviceFrameMaps(Rectifier(_camera_map(), _color(), np.zeros((12, 16, 3))), table, device)
    light = torch.rand(1, 3, 5, 7, generator=torch.Generator().manual_seed(6)) * 1.2 - 0.1
    hwc = light[0].permute(1, 2, 0).numpy()
    expected = table.table[np.arange(3), np.rint(np.clip(hwc, 0, 1) * 999).astype(int)]
    u, finite = maps.to_input(light.to(device))
    assert u.shape == (5, 7, 3) and bool(finite.cpu())
    np.testing.assert_array_equal(u.cpu().numpy(), expected)
    np.testing.assert_array_equal(u.cpu().numpy(), table.apply(light[0].permute(1, 2, 0)).numpy())


@pytest.mark.parametrize("device", DEVICES)
def test_trilinear_table_on_the_device_is_trilinear_interpolation(device):
    """Exact for an affine table (which pins the axis order), and SciPy's trilinear interpolation
    of a random table (clamped to [0, 1]^3) to float32 rounding."""
    rng = np.random.default_rng(2)
    A = np.array([[0.9, 0.2, -0.1], [0.05, 0.7, 0.3], [-0.2, 0.1, 0.6]])
    rectifier = Rectifier(_camera_map(), _color(), np.zeros((12, 16, 3)))
    light = torch.from_numpy(rng.uniform(-0.1, 1.1, size=(1, 3, 7, 9)).astype(np.float32))
    hwc = np.clip(light[0].permute(1, 2, 0).numpy().astype(np.float64), 0, 1)
    affine = ResponseLUT.from_function(lambda v: v @ A.T + 0.01, size=9)
    u, _ = DeviceFrameMaps(rectifier, TrilinearInverseTable(affine.table), device).to_input(light.to(device))
    np.testing.assert_allclose(u.cpu().numpy(), hwc @ A.T + 0.01, atol=1e-5)
    table = rng.uniform(size=(5, 5, 5, 3)).astype(np.float32)
    axis = np.linspace(0, 1, 5)
    expected = RegularGridInterpolator((axis, axis, axis), table.astype(np.float64))(hwc.reshape(-1, 3)).reshape(
        hwc.shape
    )
    u, _ = DeviceFrameMaps(rectifier, TrilinearInverseTable(table), device).to_input(light.to(device))
    np.testing.assert_allclose(u.cpu().numpy(), expected, atol=1e-5)


@pytest.mark.parametrize("device", DEVICES)
def test_non_finite_light_is_reported_not_indexed(device):
    maps = DeviceFrameMaps(
        Rectifier(_camera_map(), _color(), np.zeros((12, 16, 3))), ChannelInverseTable(np.ones((3, 8))), device
    )
    light = torch.rand(1, 3, 4, 4)
    light[0, 1, 2, 3] = float("nan")
    u, finite = maps.to_input(light.to(device))
    assert not bool(finite.cpu()) and bool(torch.isfinite(u).all())


def _half_and_half(target, captured):
    """A compensation that uses both images (its output depends on the rectified capture)."""
    return 0.5 * (target + captured)


@pytest.mark.parametrize("device", DEVICES)
def test_the_loop_on_the_device_shows_what_the_loop_on_the_cpu_shows(device):
    """The same frames through the CPU's tables and through the device's maps (a straight rig: the
    camera map falls on pixel centres, so the warps agree to float32 rounding): the rectified
    captures kept for the scores agree to 1e-5, the projector input shown to a neighbouring bin of
    the inverse response at most (a float32 difference can round o (N - 1) the other way)."""
    rig = straight_rig(HW, delta_psf(), noise_sigma=0.0)
    calibration = exact_calibration(rig)
    targets = [("a", smooth_target(0)), ("b", smooth_target(1))]
    results = {}
    for where in ("cpu tables", device):
        display = MemoryDisplay()
        shown, records = [], []

        def keep(record, shown=shown, display=display):
            shown.append(display.shown.copy())
            records.append(record)

        summary = run_live(
            _half_and_half,
            calibration,
            display,
            VirtualCamera(rig, display),
            targets,
            measure=True,
            on_frame=keep,
            device=None if where == "cpu tables" else device,
        )
        assert summary.frames == 2
        results[where] = (np.stack(shown), np.stack([r.uncompensated for r in records]), summary)
    (cpu_shown, cpu_rectified, _), (dev_shown, dev_rectified, dev_summary) = results["cpu tables"], results[device]
    assert np.abs(dev_rectified - cpu_rectified).max() < 1e-5
    assert np.abs(dev_shown - cpu_shown).mean() < 1e-4
    assert np.abs(dev_shown - cpu_shown).max() < 0.01  # one bin near black, where f^-1 = o^(1/2.2) is steepest
    # the scores of the loop on the device: the capture comes back as the target's light
    for (_, target), record in zip(targets, np.stack(dev_rectified)):
        assert np.abs(record - target).mean() < 0.02
    assert dev_summary.ssim_compensated and dev_summary.ssim_uncompensated


def test_the_loop_on_a_surface_stays_on_the_cpu():
    rig = straight_rig(HW, delta_psf(), noise_sigma=0.0)
    calibration = exact_calibration(rig).with_surface(np.full(HW + (3,), 0.8), np.zeros(HW + (3,)))
    display = MemoryDisplay()
    with pytest.raises(EdofprojError, match="on a surface runs on the CPU"):
        run_live(
            _half_and_half,
            calibration,
            display,
            VirtualCamera(rig, display),
            [("a", smooth_target())],
            surface=SurfaceLoop(calibration, _half_and_half),
            device="cpu",
        )
