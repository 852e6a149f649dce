"""Camera backends: OpenCV ``VideoCapture``, a shell command, a watched folder, the virtual ProCams.

* :class:`OpenCVCamera` -- ``opencv:0`` (a USB camera or webcam by index), ``opencv:PATH`` (a
  video file, a stream URL, or an image sequence such as ``frames/img_%04d.png``). 8- and 16-bit
  frames; BGR is turned into RGB. Exposure through ``CAP_PROP_EXPOSURE`` where the driver has it.
* :class:`CommandCamera` -- ``cmd:TEMPLATE``: the template is split like a shell line
  (:func:`shlex.split`, no shell runs) and ``{out}`` replaced by a file path in a private
  temporary folder; after the command exits 0 the newest image file there is the frame
  (tools that change the extension are fine). E.g.
  ``cmd:gphoto2 --capture-image-and-download --force-overwrite --filename {out}``.
* :class:`FolderCamera` -- ``folder:DIR``: a tethered camera writes files into ``DIR``; each
  grab waits for the next new image file and for its size to stop changing.
* :class:`VirtualCamera` -- ``virtual:DIR``: the virtual ProCams that wrote the capture folder
  ``DIR`` (``edofproj procams simulate``), looking at what the display shows.

Frames are linear RGB in ``[0, 1]`` only if the camera delivers linear data (RAW converted
linearly, or a machine-vision camera with gamma 1); see docs/procams.md.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from ...errors import EdofprojError
from ...imaging.image_io import IMAGE_EXTENSIONS, open_video, to_unit_float
from ..capture_io import read_rgb_counts
from ..virtual import VirtualProCams
from .base import Camera, Display


def video_devices_found() -> str:
    """The video devices the system lists (``/dev/video*`` on Linux), for error messages."""
    devices = sorted(glob.glob("/dev/video*"))
    return ", ".join(devices) if devices else "no /dev/video* device"


class OpenCVCamera(Camera):
    """A camera or video source opened with ``cv2.VideoCapture``."""

    def __init__(self, source: str, exposure: float | None = None) -> None:
        self.spec = f"opencv:{source}"
        self.source: int | str = int(source) if source.isdigit() else source
        self.capture = open_video(self.source)  # quietly: we raise our own error
        if not self.capture.isOpened():
            self.capture.release()
            raise EdofprojError(
                f"camera '{self.spec}' does not answer (OpenCV cannot open it); found: {video_devices_found()}"
            )
        self.exposure = exposure
        if exposure is not None and not self.capture.set(cv2.CAP_PROP_EXPOSURE, float(exposure)):
            raise EdofprojError(f"camera '{self.spec}' does not let OpenCV set its exposure")

    def grab(self) -> np.ndarray:
        return to_unit_float(self.grab_native())

    def grab_native(self) -> np.ndarray:
        """The frame as OpenCV decodes it, ``uint8`` or ``uint16`` RGB."""
        ok, frame = self.capture.read()
        if not ok or frame is None:
            raise EdofprojError(f"camera '{self.spec}' returned no frame (disconnected, or the end of the sequence)")
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        return cv2.cvtColor(frame[..., :3], cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        self.capture.release()

    def settings(self) -> dict:
        return {
            "spec": self.spec,
            "backend": "opencv",
            "exposure": self.exposure,
            "frame_hw": [
                int(self.capture.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                int(self.capture.get(cv2.CAP_PROP_FRAME_WIDTH)),
            ],
        }


def _image_files(folder: Path) -> dict[Path, float]:
    return {p: p.stat().st_mtime for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()}


#: Private folders of ``cmd:`` cameras: ``<tmp>/edofproj-camera-<pid>-XXXXXXXX``.
CAMERA_FOLDER_PREFIX = "edofproj-camera-"


def _kill_group(process: subprocess.Popen) -> None:
    """SIGKILL the process group of ``process`` (its grandchildren too) and reap it."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)
    with contextlib.suppress(Exception):
        process.communicate(timeout=5)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_stale_camera_folders(temp_dir: str | None = None) -> list[Path]:
    """Delete the ``cmd:`` camera folders (:data:`CAMERA_FOLDER_PREFIX`) of this user whose
    process is dead (killed with ``kill -9``, which skips the clean-up); returns them."""
    root = Path(temp_dir or tempfile.gettempdir())
    removed = []
    for folder in root.glob(CAMERA_FOLDER_PREFIX + "*"):
        pid_text = folder.name[len(CAMERA_FOLDER_PREFIX) :].split("-", 1)[0]
        try:
            mine = folder.is_dir() and not folder.is_symlink() and folder.stat().st_uid == os.getuid()
        except OSError:
            continue
        if mine and pid_text.isdigit() and not _pid_alive(int(pid_text)):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


class CommandCamera(Camera):
    """Runs a command that writes one image to ``{out}`` per grab (module docstring)."""

    OUT_NAME = "frame.png"

    def __init__(self, template: str, timeout_s: float = 120.0) -> None:
        self.spec = f"cmd:{template}"
        try:
            self.tokens = shlex.split(template)
        except ValueError as exc:
            raise EdofprojError(f"camera command '{template}' cannot be split: {exc}") from None
        if not self.tokens or not any("{out}" in t for t in self.tokens):
            raise EdofprojError(f"camera command '{template}' must contain {{out}}, the file it writes")
        self.timeout_s = timeout_s
        remove_stale_camera_folders()
        self._folder = tempfile.TemporaryDirectory(prefix=f"{CAMERA_FOLDER_PREFIX}{os.getpid()}-")

    def grab(self) -> np.ndarray:
        return to_unit_float(self.grab_native())

    def grab_native(self) -> np.ndarray:
        """The written file's 8- or 16-bit RGB counts."""
        folder = Path(self._folder.name)
        for old in folder.iterdir():
            old.unlink()
        out = folder / self.OUT_NAME
        command = [t.replace("{out}", str(out)) for t in self.tokens]
        try:
            # its own process group (session): on a timeout the command and every process it started are killed
            process = subprocess.Popen(
                command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
            )
        except FileNotFoundError:
            raise EdofprojError(f"camera command '{self.tokens[0]}' not found (is it installed and on PATH?)") from None
        try:
            stdout, stderr = process.communicate(timeout=self.timeout_s)
        except BaseException as exc:  # a timeout, or Ctrl-C: no camera process outlives the grab
            _kill_group(process)
            if isinstance(exc, subprocess.TimeoutExpired):
                raise EdofprojError(
                    f"camera command timed out after {self.timeout_s:g} s: {' '.join(command)}"
                ) from None
            raise
        if process.returncode != 0:
            last = (stderr or stdout).strip().splitlines()
            raise EdofprojError(
                f"camera command exited with {process.returncode}: {last[-1] if last else 'no message'}"
            )
        written = _image_files(folder)
        if not written:
            raise EdofprojError(f"camera command wrote no image file to {{out}} ({' '.join(command)})")
        return read_rgb_counts(max(written, key=written.__getitem__), what="camera frame")

    def close(self) -> None:
        self._folder.cleanup()

    def settings(self) -> dict:
        return {"spec": self.spec, "backend": "cmd", "timeout_s": self.timeout_s}


class FolderCamera(Camera):
    """Waits for each new image file a tethered camera writes into ``folder``."""

    def __init__(self, folder: str | Path, timeout_s: float = 60.0, poll_s: float = 0.05) -> None:
        self.folder = Path(folder)
        self.spec = f"folder:{self.folder}"
        if not self.folder.is_dir():
            raise EdofprojError(f"camera folder '{self.folder}' does not exist")
        self.timeout_s, self.poll_s = timeout_s, poll_s
        self._seen = set(_image_files(self.folder))

    def grab(self) -> np.ndarray:
        return to_unit_float(self.grab_native())

    def grab_native(self) -> np.ndarray:
        """The next new file's 8- or 16-bit RGB counts."""
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            new = sorted(set(_image_files(self.folder)) - self._seen, key=lambda p: p.stat().st_mtime)
            if new:
                path = new[0]
                size = -1
                while size != path.stat().st_size:  # still being written
                    size = path.stat().st_size
                    time.sleep(self.poll_s)
                self._seen.add(path)
                return read_rgb_counts(path, what="camera frame")
            time.sleep(self.poll_s)
        raise EdofprojError(f"no new image appeared in camera folder '{self.folder}' within {self.timeout_s:g} s")

    def settings(self) -> dict:
        return {"spec": self.spec, "backend": "folder", "timeout_s": self.timeout_s}


class VirtualCamera(Camera):
    """The virtual ProCams' camera looking at what ``display`` shows (black before the first frame)."""

    def __init__(self, rig: VirtualProCams, display: Display, seed: int = 0, spec: str = "virtual") -> None:
        self.rig, self.display = rig, display
        self.spec = spec
        self.rng = np.random.default_rng(seed)
        self.seed = seed

    def grab(self) -> np.ndarray:
        return self.grab_native().astype(np.float32) / np.float32(255.0)

    def grab_native(self) -> np.ndarray:
        """The virtual sensor's 8-bit counts (:meth:`VirtualProCams.capture_counts`), ``uint8``."""
        shown = self.display.shown
        if shown is None:
            shown = np.zeros(self.rig.projector_hw + (3,), dtype=np.float32)
        return self.rig.capture_counts(shown, self.rng)

    def settings(self) -> dict:
        return {"spec": self.spec, "backend": "virtual", "seed": self.seed, "camera_hw": list(self.rig.camera_hw)}
