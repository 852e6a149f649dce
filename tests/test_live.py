"""The live loop (show I, capture, rectify, compensate, show Î) through a virtual ProCams whose
calibration is known exactly (tests/virtual_rigs.py): the chain of colour spaces, --frames,
Ctrl-C, and the frame sources."""

import threading

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from edofproj.application.live import STAGES, fit_to_projector, frame_source, run_live
from edofproj.errors import EdofprojError
from edofproj.procams.devices import GrabSettings
from edofproj.procams.devices.base import Camera
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from virtual_rigs import delta_psf, exact_calibration, straight_rig

HW = (24, 32)


def smooth_target(seed=0):
    rng = np.random.default_rng(seed)
    image = np.stack([gaussian_filter(rng.uniform(0, 1, HW), 3) for _ in range(3)], axis=-1)
    return (0.1 + 0.8 * (image - image.min()) / np.ptp(image)).astype(np.float32)


def identity_net(target, captured):
    return target


@pytest.fixture
def rig_and_calibration():
    rig = straight_rig(HW, delta_psf(), noise_sigma=0.0)
    return rig, exact_calibration(rig)


def test_target_light_comes_back_as_light(rig_and_calibration):
    """With a delta PSF, showing f^-1(I) and rectifying the capture returns I: the inverse response,
    the colour unmixing and the black level undo the rig's gamma, mixing, black and ambient light."""
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    target = smooth_target()
    records = []
    summary = run_live(
        identity_net,
        calibration,
        display,
        VirtualCamera(rig, display),
        [("t", target)] * 5,
        frames=3,
        measure=True,
        on_frame=records.append,
    )
    assert summary.frames == 3 and not summary.interrupted
    assert set(summary.mean_stage_ms()) == set(STAGES) | {"check"}
    assert summary.fps > 0
    for record in records:
        assert np.abs(record.uncompensated - target).mean() < 0.02
        assert np.abs(record.compensated - target).mean() < 0.02
        # what was shown is the projector input: the target through the inverse of u^2.2
        assert np.abs(display.shown - target ** (1 / 2.2)).mean() < 0.03


def test_a_network_that_takes_contiguous_images_sees_the_rectified_capture(rig_and_calibration):
    """A network with ``channels_last_inputs = False`` gets contiguous (1, 3, H, W) captures whose
    planes are the rectified capture's channels (split from the slot's HWC buffer)."""
    rig, calibration = rig_and_calibration

    class PlanarNet:
        channels_last_inputs = False

        def __init__(self):
            self.seen = []

        def __call__(self, target, captured):
            assert captured.is_contiguous() and captured.shape == (1, 3) + HW
            self.seen.append(captured[0].permute(1, 2, 0).numpy().copy())
            return target.contiguous()  # a contiguous (1, 3, H, W) output, as such networks give

    net, records, display = PlanarNet(), [], MemoryDisplay()
    target = smooth_target(3)
    run_live(net, calibration, display, VirtualCamera(rig, display), [("t", target)] * 3, keep_images=True,
             on_frame=records.append)  # fmt: skip
    assert len(records) == len(net.seen) == 3
    for record, seen in zip(records, net.seen):
        np.testing.assert_array_equal(seen, record.uncompensated)
        assert np.abs(record.uncompensated - target).mean() < 0.02  # light comes back as light
        np.testing.assert_array_equal(
            record.compensated_input, calibration.inverse_table.apply(torch.from_numpy(target))
        )


def test_ctrl_c_stops_the_loop_after_the_frames_done(rig_and_calibration):
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    virtual = VirtualCamera(rig, display)

    class Interrupted(Camera):
        spec = "interrupted"
        grabs = 0

        def grab(self):
            self.grabs += 1
            if self.grabs == 3:
                raise KeyboardInterrupt
            return virtual.grab()

    target = smooth_target()
    summary = run_live(identity_net, calibration, display, Interrupted(), [("t", target)] * 10)
    assert summary.interrupted and summary.frames == 2
    assert all(len(summary.stage_s[stage]) == 2 for stage in STAGES)


def test_targets_of_another_size_are_refused(rig_and_calibration):
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    with pytest.raises(EdofprojError, match="calibration was made for a 24x32 projector"):
        run_live(identity_net, calibration, display, VirtualCamera(rig, display), [("t", np.zeros((20, 32, 3)))])
    with pytest.raises(EdofprojError, match="--average"):
        GrabSettings(average=0)


def test_frame_sources_cycle_images_and_refuse_another_size(tmp_path):
    import cv2

    for index in range(2):
        cv2.imwrite(str(tmp_path / f"{index}.png"), np.full(HW + (3,), 100 * index, np.uint8))
    (tmp_path / "other").mkdir()
    cv2.imwrite(str(tmp_path / "other" / "big.png"), np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(EdofprojError, match="is 48x64 but the calibration was made for a"):
        next(frame_source(HW, image=str(tmp_path / "other" / "big.png")))
    frames = frame_source(HW, images=str(tmp_path))
    names = [next(frames)[0] for _ in range(5)]
    assert names == ["0.png", "1.png", "0.png", "1.png", "0.png"]
    name, frame = next(frame_source(HW, image=str(tmp_path / "1.png")))
    assert frame.shape == HW + (3,)
    np.testing.assert_allclose(frame, 100 / 255, atol=1e-6)
    np.testing.assert_allclose(fit_to_projector(np.ones((6, 8, 3)), HW), 1.0)
    (tmp_path / "empty").mkdir()
    with pytest.raises(EdofprojError, match="holds no image"):
        next(frame_source(HW, images=str(tmp_path / "empty")))


def test_video_frames_are_read_in_order(tmp_path):
    import cv2

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    assert writer.isOpened()  # opencv-python-headless ships its own MJPG encoder
    for level in (40, 200, 120):
        writer.write(np.full((48, 64, 3), level, np.uint8))
    writer.release()
    levels = [float(frame.mean()) * 255 for _, frame in frame_source(HW, video=str(path))]
    np.testing.assert_allclose(levels, [40, 200, 120], atol=3)


def test_a_video_that_stops_decoding_halfway_ends_the_loop_in_one_line(tmp_path, rig_and_calibration):
    """The frames before the damage are shown; then the loop ends with the decoder's one-line error
    and no thread left running (live writes nothing: there is no partial output to remove)."""
    import cv2

    rig, calibration = rig_and_calibration
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    rng = np.random.default_rng(0)
    for _ in range(20):
        writer.write(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8))
    writer.release()
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = rng.integers(0, 256, 4000, dtype=np.uint8).tobytes()
    (tmp_path / "broken.avi").write_bytes(bytes(data))
    shown = []
    display = MemoryDisplay()
    with pytest.raises(EdofprojError, match=r"cannot be decoded after frame \d+ of 20"):
        run_live(
            identity_net,
            calibration,
            display,
            VirtualCamera(rig, display),
            frame_source(HW, video=str(tmp_path / "broken.avi")),
            on_frame=shown.append,
        )
    assert 0 < len(shown) < 20
    assert not live_threads()


# --------------------------------------------------------------------------- the pipelined devices


def live_threads():
    return [t for t in threading.enumerate() if t.name.startswith("edofproj-live")]


def half_net(target, captured):
    return 0.5 * target  # a compensated frame that differs from the target


class RecordingDisplay(MemoryDisplay):
    def __init__(self):
        super().__init__()
        self.history = []

    def _present(self, frame):
        super()._present(frame)
        self.history.append(frame)


def test_a_stalled_camera_is_reported_and_the_loop_resumes(rig_and_calibration):
    """The camera blocks in its 4th grab until a stall has been reported: meanwhile the display
    shows the last compensated frame; then the loop completes. (Its other grabs return a ready
    frame at once; should one of them outlast the timeout on a loaded machine, it is reported
    too, which the assertions allow.)"""
    rig, calibration = rig_and_calibration
    display = RecordingDisplay()
    target = smooth_target()
    display.show(calibration.inverse_table.apply(torch.from_numpy(target)).numpy())
    ready = VirtualCamera(rig, display).grab()
    release = threading.Event()
    lines, shown_during_stall = [], []

    class Stalling(Camera):
        spec = "stalling"
        grabs = 0

        def grab(self):
            self.grabs += 1
            if self.grabs == 4:
                assert release.wait(timeout=600), "the stall was never reported"
            return ready

    camera = Stalling()

    def report(line):
        lines.append(line)
        if "stalled" in line and camera.grabs == 4 and not release.is_set():
            shown_during_stall.append(display.shown.copy())
            release.set()

    summary = run_live(half_net, calibration, display, camera, [("t", target)] * 6, stall_timeout_s=0.2, report=report)
    assert summary.frames == 6 and summary.stalls >= 1 and not summary.interrupted
    assert release.is_set() and camera.grabs > 6  # the late frame was dropped and grabbed again
    assert all(("stalled" in line) == (i % 2 == 0) for i, line in enumerate(lines)) and "is back" in lines[-1]
    compensated = calibration.inverse_table.apply(torch.from_numpy(0.5 * target)).numpy()
    np.testing.assert_allclose(shown_during_stall[0], compensated, atol=0.5 / 255 + 1e-6)
    assert not live_threads()


def test_a_camera_that_raises_stops_the_loop_with_its_error(rig_and_calibration):
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    virtual = VirtualCamera(rig, display)

    class Failing(Camera):
        spec = "failing"
        grabs = 0

        def grab(self):
            self.grabs += 1
            if self.grabs == 3:
                raise EdofprojError("camera 'failing' was unplugged")
            return virtual.grab()

    with pytest.raises(EdofprojError, match="unplugged"):
        run_live(identity_net, calibration, display, Failing(), [("t", smooth_target())] * 10)
    assert not live_threads()


def test_camera_frames_of_another_size_and_displays_of_another_size_are_refused(rig_and_calibration):
    rig, calibration = rig_and_calibration

    class Small(Camera):
        spec = "small"

        def grab(self):
            return np.zeros((8, 10, 3), np.float32)

    with pytest.raises(EdofprojError, match="camera frame of 't' is 8x10 pixels, the calibrated camera 24x32"):
        run_live(identity_net, calibration, MemoryDisplay(), Small(), [("t", smooth_target())] * 3)
    assert not live_threads()
    with pytest.raises(EdofprojError, match="display 'memory' is 48x64 but the calibration was made for a 24x32"):
        run_live(identity_net, calibration, MemoryDisplay((48, 64)), Small(), [("t", smooth_target())])


def test_ctrl_c_in_the_calling_thread_ends_every_thread(rig_and_calibration):
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    frames = []

    def on_frame(record):
        frames.append(record)
        if len(frames) == 2:
            raise KeyboardInterrupt

    summary = run_live(
        identity_net,
        calibration,
        display,
        VirtualCamera(rig, display),
        [("t", smooth_target())] * 50,
        on_frame=on_frame,
    )
    assert summary.interrupted and 2 <= summary.frames < 50
    assert not live_threads()


def test_throughput_and_latency_are_reported_per_frame(rig_and_calibration):
    rig, calibration = rig_and_calibration
    display = MemoryDisplay()
    summary = run_live(identity_net, calibration, display, VirtualCamera(rig, display), [("t", smooth_target())] * 4)
    assert summary.frames == 4 and len(summary.latency_s) == 4
    median, p99 = summary.latency_ms()
    assert 0 < median <= p99
    # a frame's latency spans its own stages, which run one after the other in its journey
    journeys = [sum(summary.stage_s[s][i] for s in STAGES) for i in range(4)]
    assert all(latency >= journey for latency, journey in zip(summary.latency_s, journeys))
    assert set(summary.stage_ms()) == set(STAGES)
    assert summary.fps > 0 and display.frames_shown == 8


def test_the_live_command_refuses_a_camera_of_another_size_in_one_line(tmp_path, capsys):
    """On the command line: a camera whose frames are not the calibrated camera's size ends
    ``edofproj live`` with one line and exit status 2, and no thread of the loop is left."""
    from edofproj.cli import main
    from edofproj.imaging.image_io import write_image
    from edofproj.procams.capture_io import write_rgb_png
    from edofproj.procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text
    from edofproj.procams.virtual import VirtualProCams, simulate_captures

    rig = straight_rig(HW, delta_psf())
    exact_calibration(rig).save(tmp_path / "calib.npz")  # a 32x24 camera
    manifest, images = build_pattern_set(
        PatternSpec(width=HW[1], height=HW[0], dot_grid=(2, 3), color_levels=2, bernoulli_count=1)
    )
    for name, image in images.items():
        write_rgb_png(tmp_path / "pat" / name, image)
    (tmp_path / "pat" / MANIFEST_NAME).write_text(manifest_json_text(manifest))
    other = VirtualProCams(
        projector_hw=HW, camera_hw=(30, 40), psf=delta_psf()[None], homography=np.diag([1.2, 1.2, 1])
    )
    simulate_captures(other, tmp_path / "pat", tmp_path / "sim")  # the same projector seen by a 40x30 camera
    write_image(tmp_path / "target.png", torch.from_numpy(smooth_target().transpose(2, 0, 1).copy()))
    capsys.readouterr()
    args = ["live", "builtin:cpu-doe-net", "--calib", str(tmp_path / "calib.npz"), "--camera",
            f"virtual:{tmp_path / 'sim'}", "--display", "memory", "--image", str(tmp_path / "target.png")]  # fmt: skip
    assert main(args + ["--frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is 30x40 pixels, the calibrated camera 24x32" in err[0] and "Traceback" not in err[0]
    assert not live_threads()
