"""SIGTERM ends the live loop as Ctrl-C does: the frames done are summarised, every thread ends,
the previous SIGTERM handler is back, and ``edofproj live`` prints "interrupted" and its summary
and exits with code 0 (it died with -15 and no summary before)."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest
import torch

from edofproj.application.live import run_live
from edofproj.imaging.image_io import write_image
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.devices.base import Camera
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text
from edofproj.procams.virtual import simulate_captures
from virtual_rigs import delta_psf, exact_calibration, straight_rig


def identity_net(target, captured):
    return target


def live_threads():
    return [t for t in threading.enumerate() if t.name.startswith("edofproj-live")]


class Killed(Exception):
    """What the test's own SIGTERM handler raises: the loop did not handle the signal."""


def raise_killed(signum, frame):
    raise Killed


def test_sigterm_ends_the_loop_with_the_summary_of_the_frames_done():
    """The camera sends SIGTERM to this process on its first grab after a frame is on screen (the
    loop's ``on_frame``: waiting for that state, not for a number of grabs, which a loaded machine
    can reach before any frame is done); the targets never end, so only the signal can end the
    loop. Without its handling, the test's own handler raises ``Killed``."""
    rig = straight_rig((24, 32), delta_psf())
    calibration, display = exact_calibration(rig), MemoryDisplay()
    virtual = VirtualCamera(rig, display)

    shown = threading.Event()

    class Terminating(Camera):
        spec = "terminating"
        sent = False

        def grab(self):
            if shown.is_set() and not self.sent:
                self.sent = True
                os.kill(os.getpid(), signal.SIGTERM)
            return virtual.grab()

    previous = signal.signal(signal.SIGTERM, raise_killed)
    try:
        summary = run_live(
            identity_net,
            calibration,
            display,
            Terminating(),
            itertools.repeat(("t", np.full((24, 32, 3), 0.5))),
            on_frame=lambda frame: shown.set(),
        )
        assert signal.getsignal(signal.SIGTERM) is raise_killed  # restored
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert summary.interrupted and summary.frames >= 1
    assert not live_threads()


@pytest.mark.slow
def test_live_on_sigterm_prints_its_summary_and_exits_0(tmp_path):
    """``edofproj live`` on the virtual ProCams, repeating one target until stopped: SIGTERM is
    sent once the first frame is reported (a state, not a clock)."""
    hw = (96, 128)
    rig = straight_rig(hw, delta_psf())
    manifest, images = build_pattern_set(
        PatternSpec(width=hw[1], height=hw[0], dot_grid=(2, 2), color_levels=2, bernoulli_count=1)
    )
    for name, image in images.items():
        write_rgb_png(tmp_path / "pat" / name, image)
    (tmp_path / "pat" / MANIFEST_NAME).write_text(manifest_json_text(manifest))
    simulate_captures(rig, tmp_path / "pat", tmp_path / "rig")
    exact_calibration(rig).save(tmp_path / "calib.npz")
    target = np.random.default_rng(0).uniform(0.2, 0.8, (3, *hw)).astype(np.float32)
    write_image(tmp_path / "target.png", torch.from_numpy(target))
    command = [sys.executable, "-m", "edofproj.cli", "live", "builtin:cpu-doe-net", "--calib", "calib.npz"]
    command += ["--camera", "virtual:rig", "--display", "memory", "--image", "target.png"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # each line as printed
    with subprocess.Popen(
        command, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as live:
        assert live.stdout is not None
        lines = []
        for line in live.stdout:  # until the first frame is on screen
            lines.append(line)
            if line.startswith("frame "):
                break
        else:
            pytest.fail(f"live ended before a frame: {''.join(lines)} {live.stderr.read() if live.stderr else ''}")
        live.send_signal(signal.SIGTERM)
        out, err = live.communicate(timeout=300)
    output = "".join(lines) + out
    assert live.returncode == 0, (live.returncode, output, err)
    assert "interrupted" in out and "frames, throughput" in out and "ms per stage" in out, output
    assert "Traceback" not in err, err
