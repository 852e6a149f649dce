"""Devices behind the Display/Camera interfaces: spec strings, memory/file displays, the cmd:,
folder:, opencv: and virtual cameras, frame averaging and saturation, the resumable capture
session and the inverse-response table."""

import json
import sys
import threading
import time
import warnings

import cv2
import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging.image_io import read_image_array, to_unit_float
from edofproj.locking import DirectoryLockedError, directory_lock
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.color import ColorCalibration, ResponseLUT
from edofproj.procams.devices import GrabSettings, grab_frame, open_camera, open_display
from edofproj.procams.devices.base import Camera
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text
from edofproj.procams.session import capture_patterns
from edofproj.procams.virtual import CAPTURE_INFO_JSON, VirtualProCams, simulate_captures
from virtual_rigs import delta_psf, straight_rig


def write_png(path, image):
    cv2.imwrite(str(path), np.round(image[..., ::-1] * 255).astype(np.uint8))


def random_image(shape, seed=0):
    return np.round(np.random.default_rng(seed).uniform(0, 1, shape) * 255) / 255


# --------------------------------------------------------------------------- specs


def test_unknown_kinds_list_the_known_ones():
    with pytest.raises(EdofprojError, match="use one of opencv:..., cmd:..., folder:..., virtual:..."):
        open_camera("usb:0")
    with pytest.raises(EdofprojError, match="use one of screen:..., file:..., memory"):
        open_display("projector:1")


def test_opencv_camera_that_does_not_answer_says_what_was_found(tmp_path):
    with pytest.raises(EdofprojError, match=r"does not answer .*found: "):
        open_camera(f"opencv:{tmp_path}/missing_%03d.png")


def test_exposure_only_through_opencv_and_arguments_required(tmp_path):
    with pytest.raises(EdofprojError, match="--exposure"):
        open_camera(f"folder:{tmp_path}", exposure=-5)
    with pytest.raises(EdofprojError, match="needs an argument"):
        open_camera("folder:")
    with pytest.raises(EdofprojError, match="does not exist"):
        open_camera(f"folder:{tmp_path}/nothing")
    with pytest.raises(EdofprojError, match="not a folder written by 'edofproj procams simulate'"):
        open_camera(f"virtual:{tmp_path}", display=MemoryDisplay())


# --------------------------------------------------------------------------- displays


def test_memory_display_shows_8bit_frames_and_checks_size():
    display = open_display("memory")
    image = np.random.default_rng(0).uniform(-0.2, 1.2, (4, 5, 3))
    display.show(image)
    np.testing.assert_allclose(display.shown, np.round(np.clip(image, 0, 1) * 255) / 255, atol=1e-7)
    fixed = MemoryDisplay(size_hw=(4, 6))
    with pytest.raises(EdofprojError, match="image is 4x5 but display 'memory' is 4x6"):
        fixed.show(image)
    with pytest.raises(EdofprojError, match="NaN"):
        display.show(np.full((2, 2, 3), np.nan))


def test_file_display_writes_each_frame_atomically(tmp_path):
    path = tmp_path / "shown.png"
    with open_display(f"file:{path}") as display:
        for seed in range(2):
            image = random_image((6, 7, 3), seed)
            display.show(image)
            np.testing.assert_allclose(to_unit_float(read_image_array(path)), image, atol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["shown.png"]  # no temporary file left
    with pytest.raises(EdofprojError, match="must end in"):
        open_display(f"file:{tmp_path}/shown.txt")


# --------------------------------------------------------------------------- cameras


def test_cmd_camera_runs_a_script_writing_out(tmp_path):
    image = random_image((5, 8, 3), 3)
    source = tmp_path / "source.png"
    write_png(source, image)
    script = tmp_path / "shoot.py"
    script.write_text("import shutil, sys\nshutil.copy(sys.argv[1], sys.argv[2])\n")
    with open_camera(f"cmd:{sys.executable} {script} {source} {{out}}") as camera:
        np.testing.assert_allclose(camera.grab(), image, atol=1e-6)
        np.testing.assert_allclose(camera.grab(), image, atol=1e-6)
        native = camera.grab_native()  # the file's 8-bit counts
        assert native.dtype == np.uint8
        np.testing.assert_array_equal(native, np.round(image * 255).astype(np.uint8))
    failing = tmp_path / "fail.py"
    failing.write_text("import sys\nprint('no camera on the bus', file=sys.stderr)\nsys.exit(3)\n")
    with pytest.raises(EdofprojError, match="exited with 3: no camera on the bus"):
        open_camera(f"cmd:{sys.executable} {failing} {{out}}").grab()
    with pytest.raises(EdofprojError, match="wrote no image"):
        open_camera(f"cmd:{sys.executable} -c pass {{out}}").grab()
    with pytest.raises(EdofprojError, match="must contain"):
        open_camera(f"cmd:{sys.executable} {script}")
    with pytest.raises(EdofprojError, match="not found"):
        open_camera("cmd:no-such-camera-tool-here {out}").grab()


def test_folder_camera_waits_for_each_new_file(tmp_path):
    write_png(tmp_path / "old.png", random_image((4, 4, 3), 0))
    camera = open_camera(f"folder:{tmp_path}")
    image = random_image((4, 6, 3), 1)
    timer = threading.Timer(0.2, write_png, (tmp_path / "new.png", image))
    timer.start()
    start = time.monotonic()
    np.testing.assert_allclose(camera.grab(), image, atol=1e-6)  # not the old file
    assert time.monotonic() - start >= 0.15
    timer.join()
    camera.timeout_s = 0.2
    with pytest.raises(EdofprojError, match="no new image appeared"):
        camera.grab()


def test_opencv_camera_reads_an_image_sequence_in_order(tmp_path):
    images = [random_image((6, 8, 3), seed) for seed in range(3)]
    for number, image in enumerate(images):
        write_png(tmp_path / f"img_{number:03d}.png", image)
    with open_camera(f"opencv:{tmp_path}/img_%03d.png") as camera:
        for image in images[:2]:
            np.testing.assert_allclose(camera.grab(), image, atol=1e-6)
        native = camera.grab_native()  # the decoded 8-bit RGB counts
        assert native.dtype == np.uint8
        np.testing.assert_array_equal(native, np.round(images[2] * 255).astype(np.uint8))
        with pytest.raises(EdofprojError, match="returned no frame"):
            camera.grab()


class Sequence(Camera):
    spec = "sequence"

    def __init__(self, frames):
        self.frames = list(frames)

    def grab(self):
        frame = self.frames.pop(0)
        if isinstance(frame, BaseException):
            raise frame
        return frame


def test_grab_frame_averages_and_warns_with_the_saturated_fraction():
    dark, bright = np.full((4, 5, 3), 0.2, np.float32), np.full((4, 5, 3), 0.6, np.float32)
    bright[0, :2] = 1.0  # 2 of 20 pixels saturated
    with pytest.warns(UserWarning, match=r"10\.0 % of the pixels are saturated"):
        mean = grab_frame(Sequence([dark, bright]), GrabSettings(average=2))
    np.testing.assert_allclose(mean[1:], 0.4, atol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grab_frame(Sequence([dark]))
    with pytest.raises(EdofprojError, match="changed its frame size"):
        grab_frame(Sequence([dark, dark[:2]]), GrabSettings(average=2))
    with pytest.raises(EdofprojError, match="--average"):
        GrabSettings(average=0)


def test_virtual_camera_sees_what_the_display_shows():
    rig = straight_rig((8, 10), delta_psf(), noise_sigma=0.0)
    display = MemoryDisplay()
    camera = VirtualCamera(rig, display)
    image = random_image((8, 10, 3), 4)
    display.show(image)
    expected = rig.projector_output(image) @ rig.mixing_matrix.T + np.asarray(rig.ambient)  # closed form, delta PSF
    np.testing.assert_allclose(camera.grab(), np.round(expected * 255) / 255, atol=1e-6)


def test_native_frames_are_the_sensor_counts():
    """The virtual sensor's uint8 counts are grab()'s frame times 255 (same noise draws), handed on
    as they come by grab_frame(native=True) and converted otherwise; a frame at the top count warns."""
    rig = straight_rig((8, 10), delta_psf(), noise_sigma=0.01)
    image = random_image((8, 10, 3), 5)
    frames = {}
    for native in (False, True):
        display = MemoryDisplay()
        display.show(image)
        frames[native] = grab_frame(VirtualCamera(rig, display, seed=3), native=native)
    assert frames[True].dtype == np.uint8 and frames[False].dtype == np.float32
    np.testing.assert_array_equal(frames[True].astype(np.float32) / np.float32(255), frames[False])

    class Counts(Camera):
        spec = "counts"

        def __init__(self, frame):
            self.frame = frame

        def grab(self):
            return to_unit_float(self.frame)

        def grab_native(self):
            return self.frame

    saturated = np.zeros((4, 4, 3), np.uint16)
    saturated[0, :2] = 65535  # 2 of 16 pixels
    with pytest.warns(UserWarning, match="12.5 % of the pixels are saturated"):
        assert grab_frame(Counts(saturated), native=True) is saturated
    near_top = saturated.copy()
    near_top[0, :2] = 65500  # within half an 8-bit step of the top: saturated, as for float frames
    with pytest.warns(UserWarning, match="12.5 % of the pixels are saturated"):
        grab_frame(Counts(near_top), native=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert grab_frame(Counts(saturated // 2), native=True).dtype == np.uint16


def test_virtual_camera_from_a_simulated_folder_is_the_same_rig(tmp_path):
    manifest, images = build_pattern_set(
        PatternSpec(width=32, height=24, dot_grid=(2, 3), color_levels=2, bernoulli_count=1)
    )
    for name, image in images.items():
        write_rgb_png(tmp_path / "pat" / name, image)
    (tmp_path / "pat" / MANIFEST_NAME).write_text(manifest_json_text(manifest))
    psf = np.stack([delta_psf(3)[0] * 0.9 + 0.1 / 9] * 3)
    rig = VirtualProCams.example((24, 32), psf, seed=1, depth_m=0.4)
    simulate_captures(rig, tmp_path / "pat", tmp_path / "sim")
    display = MemoryDisplay()
    camera = open_camera(f"virtual:{tmp_path / 'sim'}", display=display, seed=7)
    display.show(images["white.png"])
    np.testing.assert_array_equal(camera.grab(), rig.capture(images["white.png"], np.random.default_rng(7)))


# --------------------------------------------------------------------------- capture sessions


@pytest.fixture
def pattern_dir(tmp_path):
    manifest, images = build_pattern_set(
        PatternSpec(width=20, height=16, dot_grid=(2, 2), color_levels=2, bernoulli_count=2)
    )
    folder = tmp_path / "patterns"
    for name, image in images.items():
        write_rgb_png(folder / name, image)
    (folder / MANIFEST_NAME).write_text(manifest_json_text(manifest))
    return folder, manifest, images


def test_capture_session_resumes_after_an_interruption(tmp_path, pattern_dir):
    folder, manifest, images = pattern_dir
    rig = straight_rig((16, 20), delta_psf(), noise_sigma=0.0)
    display = MemoryDisplay()
    camera = VirtualCamera(rig, display)
    out = tmp_path / "captures"

    class Interrupting(Camera):
        spec = "virtual"  # the same virtual camera, interrupted: the session is tied to its camera's spec
        grabs = 0

        def grab(self):
            self.grabs += 1
            if self.grabs == 4:
                raise KeyboardInterrupt
            return camera.grab()

    with pytest.raises(KeyboardInterrupt):
        capture_patterns(folder, out, display, Interrupting(), depth_mm=400.0)
    info = json.loads((out / CAPTURE_INFO_JSON).read_text())
    assert info["captured"] == 3 and info["complete"] is False and info["depth_mm"] == 400.0
    assert sorted(p.name for p in out.iterdir()) == sorted([e.file for e in manifest.entries[:3]] + [CAPTURE_INFO_JSON])
    with pytest.raises(EdofprojError, match="captured at --depth-mm 400.0, not 500.0"):
        capture_patterns(folder, out, display, camera, depth_mm=500.0)
    with pytest.raises(EdofprojError, match="captured with --average 1, not 2"):
        capture_patterns(folder, out, display, camera, GrabSettings(average=2), depth_mm=400.0)
    result = capture_patterns(folder, out, display, camera, depth_mm=400.0)
    assert (result.skipped, result.captured, result.total) == (3, len(manifest.entries) - 3, len(manifest.entries))
    info = json.loads((out / CAPTURE_INFO_JSON).read_text())
    assert info["complete"] is True and info["camera_hw"] == [16, 20] and info["camera"]["spec"] == "virtual"
    for entry in manifest.entries:  # every capture is of its own pattern (noise-free closed form)
        expected = rig.projector_output(images[entry.file]) @ rig.mixing_matrix.T + np.asarray(rig.ambient)
        np.testing.assert_allclose(
            to_unit_float(read_image_array(out / entry.file)), np.round(expected * 255) / 255, atol=1e-6
        )


def test_capture_session_refuses_other_folders_and_camera_sizes(tmp_path, pattern_dir):
    folder, manifest, _ = pattern_dir
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("x")
    display = MemoryDisplay()
    with pytest.raises(EdofprojError, match="not a capture session"):
        capture_patterns(
            folder, tmp_path / "busy", display, VirtualCamera(straight_rig((16, 20), delta_psf()), display)
        )
    out = tmp_path / "captures"
    capture_patterns(folder, out, display, VirtualCamera(straight_rig((16, 20), delta_psf()), display), stop_after=2)
    bigger = VirtualProCams.example((16, 20), delta_psf(), camera_scale=2.0)
    with pytest.raises(EdofprojError, match="the session's camera 16x20"):
        capture_patterns(folder, out, display, VirtualCamera(bigger, display))


def test_capture_session_is_one_writer_per_folder(tmp_path, pattern_dir):
    folder, manifest, _ = pattern_dir
    display = MemoryDisplay()
    camera = VirtualCamera(straight_rig((16, 20), delta_psf()), display)
    out = tmp_path / "captures"
    capture_patterns(folder, out, display, camera, stop_after=1)
    stale = out / ".bernoulli_00.png.tmp-abcd1234.png"  # a write a killed session left behind
    stale.write_bytes(b"partial")
    with directory_lock(out, "another capture session", "--out"):
        with pytest.raises(DirectoryLockedError, match="another capture session"):
            capture_patterns(folder, out, display, camera)
    result = capture_patterns(folder, out, display, camera)
    assert result.captured == len(manifest.entries) - 1
    assert not stale.exists() and not any(p.name.startswith(".") for p in out.iterdir())  # lock released too


# --------------------------------------------------------------------------- inverse response


def test_response_table_reproduces_an_affine_map_exactly():
    """Trilinear interpolation is exact for affine maps: checks the grid's axis order."""
    A = np.array([[0.9, 0.2, -0.1], [0.05, 0.7, 0.3], [-0.2, 0.1, 0.6]])
    offset = np.array([0.01, -0.02, 0.03])
    lut = ResponseLUT.from_function(lambda v: v @ A.T + offset, size=9)
    images = torch.rand(2, 3, 5, 7, dtype=torch.float64)
    expected = torch.einsum("ij,bjhw->bihw", torch.from_numpy(A), images) + torch.from_numpy(offset)[:, None, None]
    torch.testing.assert_close(lut(images), expected, atol=1e-5, rtol=0)


def test_inverse_response_table_inverts_a_gamma_projector():
    levels = np.linspace(0, 1, 6)
    inputs = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)
    color = ColorCalibration(np.eye(3), np.zeros(3), inputs, inputs**2.2)
    light = torch.rand(1, 3, 20, 20, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    table = color.inverse_response_lut(size=33)(light)
    direct = np.clip(color.output_to_input(light[0].permute(1, 2, 0).numpy()), 0, 1)
    assert float((table[0].permute(1, 2, 0) - torch.from_numpy(direct)).abs().mean()) < 0.005  # what it tabulates
    error = (table - light ** (1 / 2.2)).abs()  # the closed-form inverse u = o^(1/2.2)
    assert float(error.mean()) < 0.03


def test_capture_command_photographs_a_file_display(tmp_path, pattern_dir, capsys):
    """``procams capture`` with ``file:`` as display and a ``cmd:`` camera copying that file: every
    capture is its own pattern, and a second run has nothing left to do."""
    from edofproj.cli import main

    folder, manifest, images = pattern_dir
    shown = tmp_path / "shown.png"
    args = [
        "procams",
        "capture",
        "--patterns",
        str(folder),
        "--out",
        str(tmp_path / "cap"),
        "--display",
        f"file:{shown}",
        "--camera",
        f"cmd:cp {shown} {{out}}",
    ]
    with pytest.warns(UserWarning, match=r"14 of 16 captures have saturated pixels \(worst '\w+\.png': 100\.0 %"):
        assert main(args) == 0  # the 'camera' sees the patterns themselves: full fields are saturated
    for entry in manifest.entries:
        np.testing.assert_array_equal(
            read_image_array(tmp_path / "cap" / entry.file), read_image_array(folder / entry.file)
        )
    assert main(args) == 0
    assert f"captured 0 patterns ({len(manifest.entries)} already there)" in capsys.readouterr().out
    assert main(args[:-1] + ["cmd:false {out}"]) == 0  # nothing left to capture: the camera is not asked
    assert (
        main(
            [
                "procams",
                "capture",
                "--patterns",
                str(folder),
                "--out",
                str(tmp_path / "other"),
                "--display",
                "memory",
                "--camera",
                "cmd:false {out}",
            ]
        )
        == 2
    )
    assert "camera command exited with 1" in capsys.readouterr().err
    assert not (tmp_path / "other" / manifest.entries[0].file).exists()
