"""Offline compensation of a folder of images or a video, in batches, on the network path of ``live``.

A projection-mapping show whose screen depth is known in advance can be compensated before the
show: for each batch of ``B`` target frames ``I`` ``(B, 3, H, W)``,

1. the uncompensated projection is simulated, ``I* = A(I)`` (``forward``: e.g. a flat screen at
   the show's depth, :func:`edofproj.compensation.closed_loop.flat_screen`);
2. ``x = net(I, I*)`` in :func:`torch.inference_mode`, in the memory format ``live`` and
   ``edofproj bench`` use (:func:`edofproj.application.live.network_memory_format`), clamped to
   ``[0, 1]``;
3. with a calibration, ``u = f^-1(x)`` (its inverse-response table, as ``live`` shows it);
4. the frames are written: a folder of images (:func:`edofproj.procams.capture_io.atomic_folder`:
   it appears complete or not at all) or a video through OpenCV (a temporary file beside the
   output, renamed when complete and read back: the frame count and the last frame).

Faults end in one line and leave no partial output: a video that stops decoding before the frame
count its container gives ("cannot be decoded after frame N of M"), frames that did not reach the
disk (a full disk: the written video is decoded back frame by frame, and fewer frames decode than
were written), an unwritable folder. Two inputs of a folder that would give one output name
(``x.png`` and ``x.jpg``) are refused before any work (:func:`edofproj.outputs.refuse_colliding_names`).

A video output is locked while it is written (the lock file beside it, as for a folder) and the
temporary files a killed writer left beside it (``.NAME.tmp-XXXXXXXX.avi``) are removed first. Its
frame rate must lie in :data:`VIDEO_FPS_RANGE`, what both containers store (measured with
OpenCV 4.x-5.x: an MJPG ``.avi`` stores up to 1000 frames/s and writes 600 for any higher rate; a
writer below about 0.002 frames/s does not open); the rate is also read back.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np
import torch

from ..errors import EdofprojError, RecoveryWarning
from ..fileio import atomic_path, remove_stale_temp_files
from ..imaging.image_io import IMAGE_EXTENSIONS, open_video, read_image_array, to_unit_float, write_image
from ..locking import directory_lock
from ..outputs import refuse_colliding_names
from ..procams.capture_io import atomic_folder
from .live import fit_to_projector, network_memory_format

VIDEO_CODECS = {".avi": "MJPG", ".mp4": "mp4v"}
"""Video outputs by extension and the OpenCV codec (FourCC) each is written with."""
DEFAULT_VIDEO_FPS = 30.0
"""Frame rate of a video made from a folder of images."""
VIDEO_FPS_RANGE = (0.01, 1000.0)
"""Frame rates (frames/s) a video output may have: what OpenCV's writers store for both containers
(module docstring); a rate is stored to 1/1000 frame/s."""
WRITER = "edofproj compensate"
"""The command named in the lock of an output being written."""


def is_video_path(path: str | Path) -> bool:
    return Path(path).suffix.lower() in VIDEO_CODECS


@dataclass
class FrameSource:
    """Frames ``(name, (H, W, 3) float32 in [0, 1])`` of a folder or a video, all at ``size_hw``."""

    description: str
    count: int
    fps: float
    size_hw: tuple[int, int]
    frames: Iterator[tuple[str, np.ndarray]] = field(repr=False)


def _video_frames(
    path: Path, capture, first: np.ndarray, count: int, size_hw: tuple[int, int]
) -> Iterator[tuple[str, np.ndarray]]:
    number, frame = 0, first
    try:
        while True:
            yield f"frame_{number:06d}", fit_to_projector(to_unit_float(frame[..., ::-1]), size_hw)
            number += 1
            ok, frame = capture.read()
            if not ok:
                break
    finally:
        capture.release()
    if number < count:
        raise EdofprojError(f"video '{path}' cannot be decoded after frame {number} of {count}")


def open_frames(
    images: str | None = None, video: str | None = None, size_hw: tuple[int, int] | None = None
) -> FrameSource:
    """The frames of a folder (``images``, name order; each of ``size_hw``, else refused) or of a
    ``video`` (resized to ``size_hw``); ``size_hw`` defaults to the first frame's size."""
    if (images is None) == (video is None):
        raise EdofprojError("give one of --images, --video")
    if video is not None:
        path = Path(video)
        if not path.is_file():
            raise EdofprojError(f"video '{path}' does not exist")
        capture = open_video(path)
        if not capture.isOpened():
            raise EdofprojError(f"OpenCV cannot open the video '{path}'")
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        ok, first = capture.read()
        if not ok:
            capture.release()
            raise EdofprojError(f"video '{path}' has no frame OpenCV can decode")
        size = size_hw or (int(first.shape[0]), int(first.shape[1]))
        fps = fps if math.isfinite(fps) and fps > 0 else DEFAULT_VIDEO_FPS
        return FrameSource(
            f"video '{path}'", max(count, 0), fps, size, _video_frames(path, capture, first, count, size)
        )
    folder = Path(str(images))
    if not folder.is_dir():
        raise EdofprojError(f"image folder '{folder}' does not exist")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
    if not paths:
        raise EdofprojError(f"image folder '{folder}' holds no image ({', '.join(IMAGE_EXTENSIONS)})")
    refuse_colliding_names(paths, frame_file_name, what=f"the images of '{folder}'")
    first_image = read_image_array(paths[0])
    size = size_hw or (int(first_image.shape[0]), int(first_image.shape[1]))
    reference = "the calibrated projector" if size_hw is not None else f"the first image '{paths[0].name}'"

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        for path in paths:  # still images are not resized (as in live): one of another size is refused
            image = to_unit_float(read_image_array(path))
            if image.shape[:2] != tuple(size):
                raise EdofprojError(
                    f"image '{path}' is {image.shape[0]}x{image.shape[1]}, not {size[0]}x{size[1]} (height x width) like {reference}"
                )
            yield Path(frame_file_name(path)).stem, image.astype(np.float32)

    return FrameSource(f"folder '{folder}'", len(paths), DEFAULT_VIDEO_FPS, size, frames())


def frame_file_name(path: Path) -> str:
    """The output file of the input frame ``path`` (``x.jpg`` -> ``x.png``)."""
    return f"{path.stem}.png"


class FolderSink:
    """Writes frames as ``NAME.png`` into a folder that appears only when complete; a name written
    twice is refused (it would replace a frame)."""

    def __init__(self, path: str | Path, bits: int = 8, overwrite: bool = False) -> None:
        self.path, self.bits, self.overwrite = Path(path), bits, overwrite
        self.written = 0
        self._names: set[str] = set()

    def __enter__(self) -> "FolderSink":
        self._context = atomic_folder(self.path, overwrite=self.overwrite, what=WRITER)
        self._folder = self._context.__enter__()
        return self

    def write(self, name: str, frame: np.ndarray) -> None:
        file_name = f"{name}.png"
        if file_name in self._names:
            raise EdofprojError(f"two frames would both be written as '{file_name}' in '{self.path}'")
        self._names.add(file_name)
        write_image(self._folder / file_name, np.ascontiguousarray(frame.transpose(2, 0, 1)), bits=self.bits)
        self.written += 1

    def __exit__(self, *exc) -> bool | None:
        return self._context.__exit__(*exc)


class VideoSink:
    """Writes 8-bit frames into a video (:data:`VIDEO_CODECS`) that is renamed into place only when
    it reads back whole; otherwise the temporary file is removed."""

    def __init__(self, path: str | Path, fps: float, size_hw: tuple[int, int], overwrite: bool = False) -> None:
        self.path, self.fps, self.size_hw = Path(path), fps, size_hw
        if not is_video_path(self.path):
            raise EdofprojError(f"video output '{self.path}' must end in one of {', '.join(VIDEO_CODECS)}")
        low, high = VIDEO_FPS_RANGE
        if not (math.isfinite(fps) and low <= fps <= high):
            raise EdofprojError(
                f"a video's frame rate must lie in {low:g}-{high:g} frames/s (what its container stores), not {fps:g}"
            )
        if self.path.exists() and not overwrite:
            raise EdofprojError(f"'{self.path}' exists (use --overwrite to replace it)")
        self.written = 0

    def __enter__(self) -> "VideoSink":
        # one writer per video; the temporary files of a killed one are removed under its lock
        self._lock = directory_lock(self.path, WRITER, "--out", beside=True)
        self._lock.__enter__()
        try:
            stale = remove_stale_temp_files(self.path.parent, target=self.path.name)
            if stale:
                warnings.warn(
                    f"removed {len(stale)} unfinished video(s) of an interrupted write beside '{self.path}'",
                    RecoveryWarning,
                    stacklevel=2,
                )
            self._context = atomic_path(self.path)
            self._tmp = self._context.__enter__()
        except BaseException:
            self._lock.__exit__(None, None, None)
            raise
        H, W = self.size_hw
        fourcc = cv2.VideoWriter_fourcc(*VIDEO_CODECS[self.path.suffix.lower()])  # type: ignore[attr-defined]
        self._writer = cv2.VideoWriter(str(self._tmp), fourcc, self.fps, (W, H))
        if not self._writer.isOpened():
            error = EdofprojError(f"OpenCV cannot write a {self.path.suffix} video to '{self.path}'")
            self._context.__exit__(EdofprojError, error, None)  # removes the temporary file
            self._lock.__exit__(None, None, None)
            raise error
        return self

    def write(self, name: str, frame: np.ndarray) -> None:
        self._writer.write(np.ascontiguousarray(np.round(np.clip(frame, 0.0, 1.0) * 255.0).astype(np.uint8)[..., ::-1]))
        self.written += 1

    def _check_written(self) -> None:
        """Decode the video back frame by frame (a full disk loses the end, while the container
        may still announce every frame) and read its frame rate back."""
        capture = open_video(self._tmp)
        decoded = 0
        try:
            fps = float(capture.get(cv2.CAP_PROP_FPS)) if capture.isOpened() else float("nan")
            while decoded <= self.written and capture.isOpened() and capture.read()[0]:
                decoded += 1
        finally:
            capture.release()
        if decoded != self.written:
            raise EdofprojError(
                f"cannot write '{self.path}': {decoded} of the {self.written} frames written decode when the video is "
                "read back (is the disk full?); nothing was written"
            )
        if not (abs(fps - self.fps) <= max(1e-3, 1e-4 * self.fps)):
            raise EdofprojError(
                f"cannot write '{self.path}': OpenCV stored {fps:g} frames/s, not {self.fps:g}; nothing was written"
            )

    def __exit__(self, exc_type, exc, traceback) -> bool | None:
        try:
            self._writer.release()
            if exc_type is None:
                try:
                    self._check_written()
                except EdofprojError as error:
                    self._context.__exit__(EdofprojError, error, None)
                    raise
            return self._context.__exit__(exc_type, exc, traceback)
        finally:
            self._lock.__exit__(None, None, None)


@dataclass
class OfflineSummary:
    frames: int = 0
    wall_s: float = 0.0
    network_s: list[float] = field(default_factory=list)
    batch_frames: list[int] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else float("nan")

    def network_ms_per_frame(self) -> float:
        """Median over batches of the network's time per frame."""
        per_frame = [s / n for s, n in zip(self.network_s, self.batch_frames)]
        return 1e3 * float(np.median(per_frame)) if per_frame else float("nan")


def compensate_frames(
    net: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    source: FrameSource,
    forward: Callable[[torch.Tensor], torch.Tensor],
    sink: FolderSink | VideoSink,
    batch: int = 8,
    to_input: Callable[[torch.Tensor], torch.Tensor] | None = None,
    on_batch: Callable[[int], None] | None = None,
) -> OfflineSummary:
    """Compensate every frame of ``source`` in batches of ``batch`` (module docstring) into ``sink``
    (an open one). ``to_input`` maps clamped light ``(B, H, W, 3)`` to projector input (a
    calibration's inverse table); ``on_batch`` receives the number of frames done in each batch."""
    if batch < 1:
        raise EdofprojError(f"--batch {batch} must be >= 1")
    memory_format = network_memory_format(net)
    summary = OfflineSummary()
    start = time.perf_counter()
    names: list[str] = []
    images: list[np.ndarray] = []

    def flush() -> None:
        target = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous()
        with torch.inference_mode():
            # the capture from the contiguous target, as the evaluation computes it (the FFTs of a
            # channels-last one differ in the last bits)
            captured = forward(target).contiguous(memory_format=memory_format)
            target = target.contiguous(memory_format=memory_format)
            tic = time.perf_counter()
            light = net(target, captured)
            summary.network_s.append(time.perf_counter() - tic)
            frames = light.clamp(0.0, 1.0).permute(0, 2, 3, 1)
            if to_input is not None:
                frames = to_input(frames.contiguous())
        for name, frame in zip(names, frames.float().numpy()):
            sink.write(name, frame)
        summary.batch_frames.append(len(names))
        summary.frames += len(names)
        if on_batch is not None:
            on_batch(len(names))
        names.clear()
        images.clear()

    for name, image in source.frames:
        names.append(name)
        images.append(image)
        if len(names) == batch:
            flush()
    if names:
        flush()
    summary.wall_s = time.perf_counter() - start
    return summary
