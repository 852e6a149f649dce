"""``edofproj compensate RUN --images DIR | --video FILE``: a show compensated offline in batches,
on the network path of ``live``; its faults (a video that stops decoding, a full disk) end in one
line with no partial output."""

import os
import resource
import signal
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from edofproj.application.offline import VideoSink, compensate_frames, open_frames
from edofproj.cli import main
from edofproj.config import load_config
from edofproj.errors import EdofprojError
from edofproj.imaging.image_io import read_image, write_image
from tiny_configs import TINY_EVALUATION

HW = (40, 56)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from edofproj.training.trainer import train

    root = tmp_path_factory.mktemp("runs")
    train(load_config(None, TINY_EVALUATION), root / "run", progress=False)
    return root / "run"


def smooth_frames(count, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(count):
        coarse = rng.uniform(0.1, 0.9, (HW[0] // 8, HW[1] // 8, 3)).astype(np.float32)
        frames.append(cv2.resize(coarse, (HW[1], HW[0]), interpolation=cv2.INTER_CUBIC).clip(0, 1))
    return frames


def write_video(path, frames, fourcc="MJPG"):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (HW[1], HW[0]))
    assert writer.isOpened()
    for frame in frames:
        writer.write(np.round(frame[..., ::-1] * 255).astype(np.uint8))
    writer.release()


def leftovers(folder, name):
    return [p.name for p in folder.iterdir() if name in p.name]


def test_a_folder_in_batches_equals_each_image_compensated_alone(run_dir, tmp_path, capsys):
    """Batches of 2 over 3 images (the last batch short) give what 'compensate --image' gives."""
    (tmp_path / "in").mkdir()
    for index, frame in enumerate(smooth_frames(3)):
        write_image(tmp_path / "in" / f"img{index}.png", torch.from_numpy(frame.transpose(2, 0, 1).copy()))
    common = ["--depth-mm", "350", "--bits", "16"]
    args = ["compensate", str(run_dir), "--images", str(tmp_path / "in"), "--out", str(tmp_path / "out")]
    assert main(args + common + ["--batch", "2"]) == 0
    assert "3 frames" in capsys.readouterr().out
    for index in range(3):
        single = tmp_path / f"single{index}.png"
        image = str(tmp_path / "in" / f"img{index}.png")
        assert main(["compensate", str(run_dir), "--image", image, "--out", str(single)] + common) == 0
        batch = read_image(tmp_path / "out" / f"img{index}.png")
        torch.testing.assert_close(batch, read_image(single), atol=2 / 65535, rtol=0)
    # an existing output is kept unless --overwrite
    assert main(args + common) == 2
    assert "exists and is not empty" in capsys.readouterr().err


def test_video_in_video_out_keeps_every_frame(tmp_path):
    """Identity network and screen: the output video holds the input's frames (MJPG's loss apart)."""
    frames = smooth_frames(7, seed=1)
    write_video(tmp_path / "in.avi", frames)
    source = open_frames(video=str(tmp_path / "in.avi"))
    assert source.count == 7 and source.size_hw == HW
    with VideoSink(tmp_path / "out.avi", source.fps, source.size_hw) as sink:
        summary = compensate_frames(lambda target, captured: captured, source, lambda x: x, sink, batch=3)
    assert summary.frames == 7 and summary.batch_frames == [3, 3, 1] and summary.fps > 0
    back = [frame for _, frame in open_frames(video=str(tmp_path / "out.avi")).frames]
    seen = [frame for _, frame in open_frames(video=str(tmp_path / "in.avi")).frames]
    assert len(back) == 7
    distance = np.array([[np.abs(b - s).mean() for s in seen] for b in back])
    assert np.array_equal(distance.argmin(axis=1), np.arange(7))  # every frame, in order
    assert distance.diagonal().max() < 0.03  # one more JPEG generation (chroma subsampling) apart
    assert leftovers(tmp_path, ".tmp-") == []


def test_a_video_that_stops_decoding_halfway_leaves_no_output(run_dir, tmp_path, capsys):
    write_video(tmp_path / "in.avi", smooth_frames(20, seed=2))
    data = bytearray((tmp_path / "in.avi").read_bytes())
    middle = len(data) // 2
    data[middle : middle + 2000] = np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes()
    (tmp_path / "broken.avi").write_bytes(bytes(data))
    for out in ("out.avi", "out"):
        args = ["compensate", str(run_dir), "--video", str(tmp_path / "broken.avi"), "--depth-mm", "350"]
        assert main(args + ["--out", str(tmp_path / out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert "cannot be decoded after frame" in err[-1] and "of 20" in err[-1]
        assert not (tmp_path / out).exists() and leftovers(tmp_path, ".out") == []


def test_a_full_disk_while_writing_a_video_is_one_line_and_no_file(run_dir, tmp_path):
    """A file-size limit (RLIMIT_FSIZE, the signal ignored: writes fail with EFBIG as on a full
    disk) stops the video short: the command says so in one line and removes it."""
    write_video(tmp_path / "in.avi", smooth_frames(30, seed=3))
    limit = (tmp_path / "in.avi").stat().st_size // 3

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    script = "import sys; from edofproj.cli import main; sys.exit(main(sys.argv[1:]))"
    args = ["compensate", str(run_dir), "--video", str(tmp_path / "in.avi"), "--depth-mm", "350"]
    result = subprocess.run(
        [sys.executable, "-c", script, *args, "--out", str(tmp_path / "out.avi")],
        capture_output=True,
        text=True,
        preexec_fn=limited,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )
    assert result.returncode == 2, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("edofproj: error: cannot write") and "disk full" in last and "Traceback" not in result.stderr
    assert not (tmp_path / "out.avi").exists() and leftovers(tmp_path, ".out.avi") == []


def test_bad_requests_are_one_line(run_dir, tmp_path, capsys):
    (tmp_path / "in").mkdir()
    write_image(tmp_path / "in" / "a.png", torch.rand(3, *HW))
    base = ["compensate", str(run_dir), "--images", str(tmp_path / "in")]
    for extra, message in [
        (["--capture", str(tmp_path / "in" / "a.png"), "--out", str(tmp_path / "o")], "need --depth-mm"),
        (["--depth-mm", "350", "--out", str(tmp_path / "o.png")], "a folder (no extension) or a video"),
        (["--depth-mm", "350", "--out", str(tmp_path / "o.avi"), "--bits", "16"], "8-bit"),
        (["--depth-mm", "350", "--out", str(tmp_path / "o"), "--batch", "0"], "--batch 0"),
    ]:
        assert main(base + extra) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(EdofprojError, match="does not exist"):
        open_frames(video=str(tmp_path / "missing.avi"))
    with pytest.raises(EdofprojError, match="must end in one of"):
        VideoSink(tmp_path / "x.mkv", 30, HW)
    write_image(tmp_path / "in" / "b.png", torch.rand(3, 20, 30))  # still images are not resized
    with pytest.raises(
        EdofprojError, match=r"b.png' is 20x30, not 40x56 \(height x width\) like the first image 'a.png'"
    ):
        list(open_frames(images=str(tmp_path / "in")).frames)
    (tmp_path / "empty").mkdir()
    with pytest.raises(EdofprojError, match="holds no image"):
        open_frames(images=str(tmp_path / "empty"))


def test_with_a_calibration_the_output_is_projector_input(tmp_path):
    """``to_input`` (a calibration's inverse table) turns each compensated frame into projector
    input: with an identity network and screen, f^-1(I) = I^(1/2.2) for a gamma-2.2 projector."""
    from edofproj.application.offline import FolderSink
    from edofproj.procams.color import ColorCalibration
    from edofproj.procams.frame_maps import ChannelInverseTable

    levels = np.linspace(0, 1, 6)
    inputs = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)
    table = ChannelInverseTable.from_color(ColorCalibration(np.eye(3), np.zeros(3), inputs, inputs**2.2))
    (tmp_path / "in").mkdir()
    frames = smooth_frames(3, seed=4)
    for index, frame in enumerate(frames):
        write_image(tmp_path / "in" / f"f{index}.png", torch.from_numpy(frame.transpose(2, 0, 1).copy()), bits=16)
    source = open_frames(images=str(tmp_path / "in"))
    with FolderSink(tmp_path / "out", bits=16) as sink:
        compensate_frames(lambda t, c: t, source, lambda x: x, sink, batch=2, to_input=table.apply)
    for index, frame in enumerate(frames):
        written = read_image(tmp_path / "out" / f"f{index}.png").numpy().transpose(1, 2, 0)
        assert np.abs(written - frame ** (1 / 2.2)).mean() < 0.003


def test_a_flat_depth_map_compensates_like_the_flat_screen(run_dir, tmp_path):
    """--depth-map of one depth everywhere is the flat screen of --depth-mm at that depth."""
    (tmp_path / "in").mkdir()
    for index, frame in enumerate(smooth_frames(2, seed=5)):
        write_image(tmp_path / "in" / f"g{index}.png", torch.from_numpy(frame.transpose(2, 0, 1).copy()), bits=16)
    np.save(tmp_path / "flat.npy", np.full(HW, 350.0))
    base = ["compensate", str(run_dir), "--images", str(tmp_path / "in"), "--bits", "16"]
    assert main(base + ["--depth-mm", "350", "--out", str(tmp_path / "a")]) == 0
    assert main(base + ["--depth-map", str(tmp_path / "flat.npy"), "--out", str(tmp_path / "b")]) == 0
    for index in range(2):
        flat, mapped = (read_image(tmp_path / out / f"g{index}.png") for out in ("a", "b"))
        torch.testing.assert_close(mapped, flat, atol=3 / 65535, rtol=0)
    np.save(tmp_path / "small.npy", np.full((4, 4), 350.0))
    assert main(base + ["--depth-map", str(tmp_path / "small.npy"), "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()


def test_a_calibration_for_another_projector_is_one_line_and_no_output(run_dir, tmp_path, capsys):
    """Frames of another size than the calibrated projector: refused in one line, before any
    output exists (a video's frames would be resized to the projector instead, as in live)."""
    from edofproj.procams.virtual import VirtualProCams

    psf = np.zeros((1, 3, 3, 3))
    psf[:, :, 1, 1] = 1.0
    rig = VirtualProCams(projector_hw=(24, 32), camera_hw=(24, 32), psf=psf, homography=np.eye(3), supersampling=1)
    rig.ideal_calibration().save(tmp_path / "calib.npz")
    (tmp_path / "in").mkdir()
    write_image(tmp_path / "in" / "a.png", torch.rand(3, *HW))
    for out in ("o", "o.avi"):
        args = ["compensate", str(run_dir), "--images", str(tmp_path / "in"), "--depth-mm", "350"]
        assert main(args + ["--calib", str(tmp_path / "calib.npz"), "--out", str(tmp_path / out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "a.png' is 40x56, not 24x32 (height x width) like the calibrated projector" in err[0]
        assert not (tmp_path / out).exists() and leftovers(tmp_path, ".o") == []
