"""A failing command writes exactly one line to stderr, through the CLI in a fresh process: nothing
from the libraries under edofproj (OpenCV's log and its AVI parser, FFmpeg's log, Pillow's
warnings about damaged metadata) and no note about the configuration of a shipped run."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.slow

DOE = "src/edofproj/builtin_runs/cpu-doe-net/doe.npz"


def stderr_lines(*argv: str, cwd) -> list[str]:
    """Run ``edofproj ARGV`` in a fresh process (so that warnings shown once per process and
    libraries' one-time set-up count) and return its stderr lines, expecting exit code 2."""
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}  # edofproj's own default
    done = subprocess.run(
        [sys.executable, "-m", "edofproj.cli", *argv], capture_output=True, text=True, cwd=cwd, env=env, timeout=300
    )
    assert done.returncode == 2, done.stderr
    return done.stderr.splitlines()


def encoded(suffix: str) -> bytes:
    pixels = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    return cv2.imencode(suffix, pixels)[1].tobytes()


#: Damaged videos, each one that made a library print its own line before edofproj's.
VIDEOS = {
    "no-moov.mp4": b"\x00\x00\x00\x18ftypmp42" + bytes(300),  # FFmpeg: "moov atom not found"
    "header-only.avi": b"RIFF\x00\x00\x00\x00AVI LIST",  # OpenCV's AVI parser: "Unexpected list type"
    "text.mkv": b"hello world" * 30,  # FFmpeg: "EBML header parsing failed", "Truncating packet"
}


@pytest.mark.parametrize("name", list(VIDEOS))
def test_a_damaged_video_on_a_shipped_run_is_refused_in_one_line(tmp_path, name):
    (tmp_path / name).write_bytes(VIDEOS[name])
    lines = stderr_lines(
        "compensate", "builtin:cpu-doe-net", "--video", name, "--depth-mm", "400", "--out", "out.avi", cwd=tmp_path
    )
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: ") and name in lines[0], lines
    assert not (tmp_path / "out.avi").exists()


#: Damaged images: a truncated BMP (OpenCV's ERROR log), a TIFF cut after its header (libtiff's
#: errors through OpenCV's log, Pillow's "Corrupt EXIF data" warning).
IMAGES = {
    "cut.bmp": lambda: encoded(".bmp")[:40],
    "cut.tif": lambda: encoded(".tif")[:40],
}


@pytest.mark.parametrize("name", list(IMAGES))
def test_a_damaged_image_is_refused_in_one_line(tmp_path, name):
    (tmp_path / name).write_bytes(IMAGES[name]())
    doe = os.path.join(os.path.dirname(__file__), "..", DOE)
    lines = stderr_lines("render", "--image", name, "--doe", doe, "--depth-mm", "400", "--out", "r.png", cwd=tmp_path)
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: cannot read image"), lines
