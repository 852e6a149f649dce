"""The live loop on a projector, pipelined: show ``I``, capture ``I*``, rectify, compensate, show ``Î``.

Spaces (docs/procams.md): the target ``I`` and the network's output are projector *output
light* per projector pixel (full primary = 1); a camera frame is linear *camera* RGB; what a
display receives is projector *input*. Per frame:

1. ``show_target``: send ``f^-1(I)`` (the inverse of the measured response, cached per target)
   and wait until shown;
2. ``capture``: grab the camera frame ``c`` (settle delay, averaging: :func:`grab_frame`), in the
   dtype the sensor delivers (``uint8``/``uint16`` counts: ``native``);
3. ``rectify``: ``I* = M^-1 c(q(x)) - M^-1 c_black(q(x))`` in projector pixels
   (:class:`~edofproj.procams.frame_maps.Rectifier`: precomputed ``cv2.remap`` maps, the frame
   warped in its own dtype, black level and colour unmixing folded into one transform);
4. ``compensate``: ``x = net(I, I*)``, the network alone, in the memory format ``edofproj bench``
   times it in (:func:`network_memory_format`);
5. ``to_input``: ``u = f^-1(clamp(x, 0, 1))`` (:attr:`ProCamsCalibration.inverse_table`);
6. ``show_compensated``: send ``u``.

Three threads joined by bounded queues, so that the frame rate is set by the slowest stage and
not by the sum of the stages:

* the **device** thread owns the display: it shows a target, has it captured, hands the capture
  to the compute thread (a queue of one: back-pressure) and shows each compensated frame as soon
  as it is ready -- frame ``n + 1`` is captured while frame ``n`` is computed, and between two
  captures this thread only shows;
* the **camera** thread runs :func:`grab_frame`, so that a camera that returns nothing for
  ``stall_timeout_s`` is reported in one line while the display goes back to the last good
  compensated frame; when frames come back the late one is dropped (it may show the compensated
  frame), the target is shown again and the loop goes on;
* the **calling** thread computes steps 3-5 in buffers allocated once (a free list of
  :data:`PIPELINE_SLOTS` slots; only the network allocates its own output) and receives Ctrl-C.

Throughput (frames shown per second) and latency (target taken -> its compensated frame on
screen) are reported separately (:class:`LiveSummary`). With ``measure`` the compensated
projection is captured and rectified too (``check``, not in the frame time; frame ``n + 1`` is
then captured only after frame ``n`` was shown and checked), and both captures are scored with
SSIM against ``I``. Ctrl-C (``KeyboardInterrupt`` in the calling thread, or
raised by a device) or SIGTERM (:func:`sigterm_as_ctrl_c`) ends the loop with the summary of the
frames done; a device error (a camera frame of the wrong size, a camera
that raises) ends it and is raised in the calling thread. Either way every thread the loop
started has ended when :func:`run_live` returns.

On a coloured, textured object whose surface the calibration holds, ``surface``
(:class:`~.surface_frames.SurfaceLoop`) changes steps 1, 4 and the scores: the target shown first
is the photometric correction ``f^-1(D)`` of the goal ``g`` (the target scaled into what the
surface can show), the network is given the absolute capture and the surface (or runs after the
photometric correction), and the captures are scored against ``g`` as absolute light.

With ``device`` (a GPU), steps 3-5 run there (:class:`~edofproj.procams.device_frame_maps.DeviceFrameMaps`:
the same maps as tensors): the camera frame is copied to the device in its own dtype through
page-locked memory, rectified, compensated and turned into projector input there, and only the
projector input ``(H, W, 3)`` comes back (the rectified capture too with ``measure`` or
``keep_images``). The network must already be on ``device``; the stage times wait for the device
at the end of each stage, so that each stage is charged its own device time.
"""

from __future__ import annotations

import queue
import signal
import threading
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import IMAGE_EXTENSIONS, open_video, read_image_array, to_unit_float
from ..metrics import ssim
from ..procams.calibration import ProCamsCalibration
from ..procams.device_frame_maps import DeviceFrameMaps
from ..procams.devices import Camera, Display, GrabSettings, grab_frame
from .surface_frames import SurfaceLoop

STAGES = ("show_target", "capture", "rectify", "compensate", "to_input", "show_compensated")
DEFAULT_STALL_TIMEOUT_S = 2.0
"""A camera that returns no frame for this long is reported stalled (``live --stall-timeout-s``)."""
PIPELINE_SLOTS = 4
"""Frames in flight at most: one captured, one queued, one computed, one shown."""
TARGET_CACHE_SIZE = 64
"""Targets whose tensors and inverse response are kept (a folder's images; a video's are new each frame)."""
POLL_S = 0.05
"""How often a waiting thread looks at the stop flag (waits themselves last until their state comes)."""


def _to_tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(image, dtype=np.float32).transpose(2, 0, 1)))[None]


def fit_to_projector(image: np.ndarray, size_hw: tuple[int, int]) -> np.ndarray:
    """``image (h, w, 3)`` resized to the projector's ``(H, W)`` (area averaging when shrinking)."""
    H, W = size_hw
    if image.shape[:2] == (H, W):
        return image.astype(np.float32)
    shrink = image.shape[0] > H or image.shape[1] > W
    return cv2.resize(image.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _still_at_projector_size(path: Path, size_hw: tuple[int, int]) -> np.ndarray:
    """A target image file, refused unless it has the calibrated projector's size (only a
    video's frames are resized: docs/procams.md)."""
    image = to_unit_float(read_image_array(path))
    if image.shape[:2] != tuple(size_hw):
        raise EdofprojError(
            f"image '{path}' is {image.shape[0]}x{image.shape[1]} but the calibration was made for a "
            f"{size_hw[0]}x{size_hw[1]} projector (height x width)"
        )
    return image.astype(np.float32)


def frame_source(
    size_hw: tuple[int, int], image: str | None = None, images: str | None = None, video: str | None = None
) -> Iterator[tuple[str, np.ndarray]]:
    """Target frames ``(name, (H, W, 3) in [0, 1])`` at the projector's size: one image repeated,
    a folder's images in turn (repeated), each of the projector's size (else refused), or a
    video's frames until its end (resized to the projector; a video that stops decoding before
    the frame count its container gives raises "cannot be decoded after frame N of M")."""
    if sum(x is not None for x in (image, images, video)) != 1:
        raise EdofprojError("give one of --image, --images, --video")
    if video is not None:
        if not Path(video).is_file():
            raise EdofprojError(f"video '{video}' does not exist")
        capture = open_video(video)
        if not capture.isOpened():
            raise EdofprojError(f"OpenCV cannot open the video '{video}'")
        count, number = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0
        try:
            while True:
                ok, frame = capture.read()
                if not ok:
                    break
                yield f"{Path(video).name}#{number}", fit_to_projector(to_unit_float(frame[..., ::-1]), size_hw)
                number += 1
        finally:
            capture.release()
        if number < count:
            raise EdofprojError(f"video '{video}' cannot be decoded after frame {number} of {count}")
        return
    if image is not None:
        paths = [Path(image)]
    else:
        folder = Path(str(images))
        if not folder.is_dir():
            raise EdofprojError(f"image folder '{folder}' does not exist")
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
        if not paths:
            raise EdofprojError(f"image folder '{folder}' holds no image ({', '.join(IMAGE_EXTENSIONS)})")
    targets = [(p.name, _still_at_projector_size(p, size_hw)) for p in paths]
    while True:
        yield from targets


def score_against(rectified: np.ndarray, target: torch.Tensor) -> float:
    """SSIM of a rectified capture (clipped to ``[0, 1]``) against the target ``(1, 3, H, W)``."""
    return float(ssim(_to_tensor(np.clip(rectified, 0.0, 1.0)), target)[0])


def network_memory_format(net: Callable) -> torch.memory_format:
    """The memory format of the network's inputs, as ``edofproj bench`` times it: ``channels_last``
    (weights too) unless the network says ``channels_last_inputs = False``."""
    if isinstance(net, torch.nn.Module):
        net.eval().to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # documented; not in stubs
    return torch.channels_last if getattr(net, "channels_last_inputs", True) else torch.contiguous_format


@dataclass
class LiveFrame:
    """One frame of the loop: its target, stage times and latency (s); the rectified captures and the
    projector input when :func:`run_live` keeps images."""

    name: str
    target: np.ndarray
    uncompensated: np.ndarray | None
    compensated_input: np.ndarray | None
    stage_s: dict[str, float]
    latency_s: float = float("nan")
    compensated: np.ndarray | None = None
    ssim_uncompensated: float | None = None
    ssim_compensated: float | None = None


def _percentile_ms(values: list[float], q: float) -> float:
    return 1e3 * float(np.percentile(values, q)) if values else float("nan")


@dataclass
class LiveSummary:
    """Frames shown, their stage times, latencies and the loop's wall time (s)."""

    frames: int = 0
    interrupted: bool = False
    stage_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES + ("check",)})
    stage_cpu_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES + ("check",)})
    latency_s: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    stalls: int = 0
    ssim_uncompensated: list[float] = field(default_factory=list)
    ssim_compensated: list[float] = field(default_factory=list)

    @property
    def fps(self) -> float:
        """Throughput: compensated frames shown per second of the loop's wall time."""
        return self.frames / self.wall_s if self.frames and self.wall_s > 0 else float("nan")

    def mean_stage_ms(self) -> dict[str, float]:
        return {s: 1e3 * float(np.mean(t)) for s, t in self.stage_s.items() if t}

    def stage_ms(self) -> dict[str, tuple[float, float]]:
        """``{stage: (median, 99th percentile)}`` in ms, for the stages that ran."""
        return {s: (_percentile_ms(t, 50), _percentile_ms(t, 99)) for s, t in self.stage_s.items() if t}

    def stage_cpu_ms(self) -> dict[str, float]:
        """``{stage: median}`` of the CPU time of the thread that ran it, ms: the stage's own cost,
        which does not count the time its thread waited for a core (``capture``: the camera thread's)."""
        return {s: _percentile_ms(t, 50) for s, t in self.stage_cpu_s.items() if t}

    def cpu_limited_fps(self) -> float:
        """The throughput the threads' CPU times allow with a core each: ``1 / max`` over the three
        threads of their stages' median CPU time per frame (``check`` excluded)."""
        cpu = self.stage_cpu_ms()
        device = cpu.get("show_target", 0.0) + cpu.get("show_compensated", 0.0)
        compute = sum(cpu.get(s, 0.0) for s in ("rectify", "compensate", "to_input"))
        busiest = max(device, cpu.get("capture", 0.0), compute)
        return 1e3 / busiest if busiest > 0 else float("nan")

    def latency_ms(self) -> tuple[float, float]:
        """Median and 99th percentile of target taken -> compensated frame on screen, ms."""
        return _percentile_ms(self.latency_s, 50), _percentile_ms(self.latency_s, 99)


class _StageClock:
    """Wall-clock and thread-CPU seconds of each stage of one frame (each stage runs in one thread)."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._start = (0.0, 0.0)

    def start(self) -> None:
        self._start = (time.perf_counter(), time.thread_time())

    def stop(self, stage: str) -> float:
        """Record ``stage`` since :meth:`start`; the wall-clock time now."""
        now = time.perf_counter()
        self.wall[stage] = now - self._start[0]
        self.cpu[stage] = time.thread_time() - self._start[1]
        return now


class _Stopped(Exception):
    """The loop is stopping: a waiting thread gives up."""


def _wait_put(q: queue.Queue, item: Any, stop: threading.Event) -> None:
    while True:
        try:
            q.put(item, timeout=POLL_S)
            return
        except queue.Full:
            if stop.is_set():
                raise _Stopped from None


def sigterm_as_ctrl_c() -> Callable[[], None]:
    """Handle SIGTERM (``kill PID``, a service manager stopping the loop) as Ctrl-C until the
    returned function is called: the handler raises ``KeyboardInterrupt`` in the calling thread,
    so the loop ends with the summary of the frames done instead of dying without one. Installed
    only from the main thread (the one Python runs signal handlers in); the returned function
    restores the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)

    def restore() -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)

    return restore


def _wait_get(q: queue.Queue, stop: threading.Event | None = None) -> Any:
    while True:
        try:
            return q.get(timeout=POLL_S)
        except queue.Empty:
            if stop is not None and stop.is_set():
                raise _Stopped from None


class CameraWorker:
    """The camera in its own thread: :meth:`request` a grab, :meth:`result` waits for it.

    A grab that raises (any exception, ``KeyboardInterrupt`` included) is re-raised by
    :meth:`result`. Saturated pixels are warned about on the first frame only (a warning per frame would repeat
    the same line). :meth:`close` lets the current grab finish and ends the thread.
    """

    def __init__(self, camera: Camera, grab: GrabSettings) -> None:
        self.camera, self.grab = camera, grab
        self._warn = True
        self.last_cpu_s = 0.0
        self._requests: queue.Queue = queue.Queue(maxsize=1)
        self._results: queue.Queue = queue.Queue()  # one request at a time: never more than one result
        self.thread = threading.Thread(target=self._run, name="edofproj-live-camera", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while True:
            request = self._requests.get()
            if request is None:
                return
            start_cpu = time.thread_time()
            try:
                result: Any = grab_frame(self.camera, self.grab, request, warn=self._warn, native=True)
                self._warn = False
            except BaseException as exc:  # handed to the device thread, which stops the loop
                result = exc
            self._results.put((result, time.thread_time() - start_cpu))

    def request(self, what: str) -> None:
        self._requests.put(what)

    def result(self, timeout_s: float) -> np.ndarray:
        """The frame requested last; ``queue.Empty`` after ``timeout_s`` without one. The camera
        thread's CPU time for it is :attr:`last_cpu_s`."""
        result, self.last_cpu_s = self._results.get(timeout=timeout_s)
        if isinstance(result, BaseException):
            raise result
        return result

    def close(self, join_timeout_s: float) -> None:
        """End the thread after its current grab (waits ``join_timeout_s`` at most for a stuck camera)."""
        try:
            self._requests.put_nowait(None)
        except queue.Full:  # a request not yet taken: replace it
            try:
                self._requests.get_nowait()
            except queue.Empty:
                pass
            self._requests.put_nowait(None)
        self.thread.join(join_timeout_s)


@dataclass
class _Job:
    """A frame in flight between the device and the compute threads."""

    name: str
    target: np.ndarray
    light: torch.Tensor
    frame: np.ndarray
    taken: float
    stages: "_StageClock"
    slot: int = -1
    shown: float = float("nan")
    record: LiveFrame | None = None


@dataclass
class _Slot:
    """Buffers of one frame in flight: the rectified capture and the projector input (and, for a
    loop on a GPU, page-locked copies of the camera frame per dtype, made on first use)."""

    rectified: np.ndarray
    captured: torch.Tensor
    copy_captured: bool
    captured_planes: list[np.ndarray]
    projector_input: np.ndarray
    projector_input_t: torch.Tensor
    staging: dict[Any, torch.Tensor] = field(default_factory=dict)

    def staging_for(self, frame: np.ndarray) -> torch.Tensor | None:
        """A page-locked host tensor for ``frame`` (pinned memory when the loop runs on a GPU)."""
        if not self.projector_input_t.is_pinned():
            return None
        key = (frame.shape, frame.dtype.str)
        if key not in self.staging:
            self.staging[key] = torch.from_numpy(np.ascontiguousarray(frame)).clone().pin_memory()
        return self.staging[key]


def _slot(height_width: tuple[int, int], memory_format: torch.memory_format, pinned: bool = False) -> _Slot:
    rectified = np.empty(height_width + (3,), np.float32)
    hwc_view = torch.from_numpy(rectified).permute(2, 0, 1)[None]  # channels_last (1, 3, H, W)
    contiguous = memory_format != torch.channels_last
    captured = torch.empty((1, 3) + height_width) if contiguous else hwc_view
    # pinned: the device's result is copied straight into the buffer the display reads
    projector_input_t = torch.empty(height_width + (3,), pin_memory=pinned)
    planes = [captured[0, channel].numpy() for channel in range(3)] if contiguous else []
    return _Slot(rectified, captured, contiguous, planes, projector_input_t.numpy(), projector_input_t)


class _Devices:
    """The device thread (module docstring): targets in; captures rectified and handed to the
    compute thread; compensated frames turned into projector input and shown."""

    def __init__(
        self,
        calibration: ProCamsCalibration,
        display: Display,
        camera: CameraWorker,
        targets: Iterable[tuple[str, np.ndarray]],
        frames: int | None,
        measure: bool,
        keep_images: bool,
        stall_timeout_s: float,
        memory_format: torch.memory_format,
        report: Callable[[str], None],
        surface: SurfaceLoop | None = None,
        device: torch.device | None = None,
    ) -> None:
        self.surface, self.device = surface, device
        self.calibration, self.display, self.camera = calibration, display, camera
        self.targets, self.frames, self.measure, self.keep_images = targets, frames, measure, keep_images
        self.stall_timeout_s, self.memory_format, self.report = stall_timeout_s, memory_format, report
        H, W = calibration.projector_hw
        pinned = device is not None and device.type == "cuda"
        self.slots = [_slot((H, W), memory_format, pinned) for _ in range(PIPELINE_SLOTS)]
        self.free: queue.Queue = queue.Queue()
        for index in range(PIPELINE_SLOTS):
            self.free.put(index)
        self.captures: queue.Queue = queue.Queue(maxsize=1)  # device -> compute: _Job, None at the end
        self.compensated: queue.Queue = queue.Queue(maxsize=1)  # compute -> device: _Job, None at the end
        self.done: queue.Queue = queue.Queue()  # device -> caller: shown _Job, None at the end
        self.stop = threading.Event()
        self.ended = threading.Event()  # set when the device thread is about to end
        self.error: BaseException | None = None
        self.stalls = 0
        self.last_shown: np.ndarray | None = None
        self._cache: OrderedDict[int, tuple[np.ndarray, torch.Tensor, np.ndarray]] = OrderedDict()
        self.thread = threading.Thread(target=self._run, name="edofproj-live-devices", daemon=True)

    def _target(self, name: str, target: np.ndarray) -> tuple[torch.Tensor, np.ndarray]:
        """The target as a network input and as projector input ``f^-1(I)``, cached per target."""
        key = id(target)
        if key in self._cache and self._cache[key][0] is target:
            self._cache.move_to_end(key)
            return self._cache[key][1], self._cache[key][2]
        self.calibration.check_projector_hw(target.shape[:2], what=f"target '{name}'")
        hwc = np.ascontiguousarray(target, dtype=np.float32)
        light = torch.from_numpy(hwc).permute(2, 0, 1)[None]
        if self.surface is not None:  # the network's input and the photometric correction, shown first
            light, first = self.surface.prepare(light, what=f"target '{name}'")
            hwc = np.ascontiguousarray(first[0].permute(1, 2, 0).numpy(), dtype=np.float32)
        light = light.contiguous(memory_format=self.memory_format)
        if self.device is not None:
            light = light.to(self.device)
        shown = self.calibration.inverse_table.apply(torch.from_numpy(hwc)).numpy()
        self._cache[key] = (target, light, shown)
        while len(self._cache) > TARGET_CACHE_SIZE:
            self._cache.popitem(last=False)
        return light, shown

    def _grab(self, what: str, shown: np.ndarray) -> np.ndarray:
        """A frame of ``shown`` (on screen now); through a stall (module docstring) if need be."""
        self.camera.request(what)
        try:
            return self.camera.result(self.stall_timeout_s)
        except queue.Empty:
            pass
        self.stalls += 1
        stalled = time.perf_counter()
        if self.last_shown is not None:
            self.display.show(self.last_shown)
        self.report(
            f"camera '{self.camera.camera.spec}' returned no frame for {self.stall_timeout_s:g} s (stalled); "
            + ("showing the last compensated frame" if self.last_shown is not None else "waiting")
        )
        while True:
            try:
                self.camera.result(POLL_S)  # the late frame may have seen the compensated frame: dropped
                break
            except queue.Empty:
                if self.stop.is_set():
                    raise _Stopped from None
        self.report(f"camera '{self.camera.camera.spec}' is back after {time.perf_counter() - stalled:.1f} s")
        self.display.show(shown)
        return self._grab(what, shown)

    def _show_ready(self, block: bool) -> bool:
        """Show the compensated frames that are ready (wait for one if ``block``); False at the end mark."""
        while True:
            try:
                job = _wait_get(self.compensated, self.stop) if block else self.compensated.get_nowait()
            except queue.Empty:
                return True
            if job is None:
                return False
            slot = self.slots[job.slot]
            job.stages.start()
            self.display.show(slot.projector_input)
            job.shown = job.stages.stop("show_compensated")
            record = LiveFrame(job.name, job.target, None, None, job.stages.wall, latency_s=job.shown - job.taken)
            if self.keep_images or self.measure:
                record.uncompensated, record.compensated_input = slot.rectified.copy(), slot.projector_input.copy()
            if self.measure:
                job.stages.start()
                check = self._grab(f"check of '{job.name}'", slot.projector_input)
                if check.dtype.kind in "ui":  # the camera's counts (grab_frame native)
                    check = to_unit_float(check)
                # the direct rectification, not the compute thread's rectifier (its buffers are in use)
                record.compensated = self.calibration.to_output_space(check).astype(np.float32)
                job.stages.stop("check")
            job.record = record
            self.last_shown = self.display.shown  # the slot is reused: keep the display's own copy
            self.free.put(job.slot)
            self.done.put(job)
            block = False

    def _run(self) -> None:
        captured = 0
        try:
            for name, target in self.targets:
                if self.stop.is_set() or (self.frames is not None and captured >= self.frames):
                    break
                taken = time.perf_counter()
                light, shown = self._target(name, target)
                stages = _StageClock()
                stages.start()
                self.display.show(shown)
                stages.stop("show_target")
                stages.start()
                frame = self._grab(f"capture of '{name}'", shown)
                stages.stop("capture")
                stages.cpu["capture"] = self.camera.last_cpu_s  # the camera thread's
                self.calibration.rectifier.check_frame(frame, what=f"camera frame of '{name}'")
                _wait_put(self.captures, _Job(name, target, light, frame, taken, stages), self.stop)
                captured += 1
                # with measure, frame n is shown and checked before n + 1 is captured: the captures
                # come in a fixed order (capture, check, capture, ...), whatever the machine's speed
                self._show_ready(block=self.measure)
        except _Stopped:
            pass
        except BaseException as exc:  # a device error or Ctrl-C raised by a device: the calling thread decides
            self.error = exc
        try:
            _wait_put(self.captures, None, self.stop)
            while self._show_ready(block=True):
                pass
        except _Stopped:
            pass
        except BaseException as exc:
            self.error = self.error or exc
        finally:
            self.done.put(None)
            self.ended.set()


def _compute_on_device(
    job: _Job,
    slot: _Slot,
    net: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    maps: DeviceFrameMaps,
    memory_format: torch.memory_format,
    keep_rectified: bool,
    wait: Callable[[], None] | None,
) -> None:
    """Steps 3-5 on ``maps.device`` (module docstring), the projector input into ``slot``."""
    with torch.inference_mode():
        job.stages.start()
        frame = maps.upload(job.frame, slot.staging_for(job.frame))
        job.frame = np.empty(0)  # used up
        captured = maps.rectify(frame).contiguous(memory_format=memory_format)
        if keep_rectified:  # the rectified capture, for the scores and the kept images
            torch.from_numpy(slot.rectified).copy_(captured[0].permute(1, 2, 0))
        if wait is not None:
            wait()
        job.stages.stop("rectify")
        job.stages.start()
        compensated = net(job.light, captured)
        if wait is not None:
            wait()
        job.stages.stop("compensate")
        job.stages.start()
        projector_input, finite = maps.to_input(compensated)
        slot.projector_input_t.copy_(projector_input)  # waits for the device
        if not bool(finite.cpu()):
            raise EdofprojError("the projector output light holds NaN or infinite values")
        job.stages.stop("to_input")


def run_live(
    net: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    calibration: ProCamsCalibration,
    display: Display,
    camera: Camera,
    targets: Iterable[tuple[str, np.ndarray]],
    grab: GrabSettings = GrabSettings(),
    frames: int | None = None,
    measure: bool = False,
    on_frame: Callable[[LiveFrame], None] | None = None,
    stall_timeout_s: float = DEFAULT_STALL_TIMEOUT_S,
    report: Callable[[str], None] | None = None,
    keep_images: bool = False,
    surface: SurfaceLoop | None = None,
    device: torch.device | str | None = None,
) -> LiveSummary:
    """Run the loop (module docstring) over ``targets`` until ``frames`` frames, their end or Ctrl-C.

    ``on_frame`` receives each frame once it is on screen (with its rectified capture and
    projector input when ``keep_images`` or ``measure``); ``report`` the one-line device messages
    (a stalled camera; default: a ``RuntimeWarning``); ``surface``: compensate on the calibration's
    surface (module docstring); ``device``: rectify, compensate and invert the response there (the
    network already on it; module docstring), None: on the CPU with OpenCV's tables.
    """
    if not (np.isfinite(stall_timeout_s) and stall_timeout_s > 0):
        raise EdofprojError(f"--stall-timeout-s {stall_timeout_s} must be > 0")
    H, W = calibration.projector_hw
    if display.size_hw is not None and tuple(display.size_hw) != (H, W):
        h, w = display.size_hw
        raise EdofprojError(
            f"display '{display.spec}' is {h}x{w} but the calibration was made for a {H}x{W} projector (height x width)"
        )
    report = report or (lambda line: warnings.warn(line, RuntimeWarning, stacklevel=2))
    memory_format = network_memory_format(net)
    rectify, inverse = calibration.rectifier, calibration.inverse_table  # built before the clock starts
    on_device = torch.device(device) if device is not None else None
    if on_device is not None and surface is not None:
        raise EdofprojError("the live loop on a surface runs on the CPU: leave out --device (or use --device cpu)")
    maps = DeviceFrameMaps(rectify, inverse, on_device) if on_device is not None else None
    wait = (lambda: torch.cuda.synchronize(on_device)) if on_device is not None and on_device.type == "cuda" else None
    keep_rectified = keep_images or measure
    summary = LiveSummary()
    worker = CameraWorker(camera, grab)
    devices = _Devices(
        calibration,
        display,
        worker,
        targets,
        frames,
        measure,
        keep_images,
        stall_timeout_s,
        memory_format,
        report,
        surface,
        on_device,
    )
    clock = time.perf_counter
    started = clock()
    last_shown = started

    def finish(job: _Job) -> None:
        nonlocal last_shown
        summary.frames += 1
        last_shown = job.shown
        summary.latency_s.append(job.shown - job.taken)
        for stage, seconds in job.stages.wall.items():
            summary.stage_s[stage].append(seconds)
            summary.stage_cpu_s[stage].append(job.stages.cpu[stage])
        record = job.record
        if record is not None and record.compensated is not None and record.uncompensated is not None:
            reference = _to_tensor(job.target)
            uncompensated, compensated = record.uncompensated, record.compensated
            if surface is not None:  # absolute light against the goal
                reference = surface.goal(reference)
                uncompensated, compensated = uncompensated + surface.offset_hwc, compensated + surface.offset_hwc
            record.ssim_uncompensated = score_against(uncompensated, reference)
            record.ssim_compensated = score_against(compensated, reference)
            summary.ssim_uncompensated.append(record.ssim_uncompensated)
            summary.ssim_compensated.append(record.ssim_compensated)
        if on_frame is not None and record is not None:
            on_frame(record)

    def drain(block: bool) -> bool:
        """Finish shown frames (wait for one if ``block``); False once the device thread has ended."""
        while True:
            try:
                job = _wait_get(devices.done) if block else devices.done.get_nowait()
            except queue.Empty:
                return True
            if job is None:
                return False
            finish(job)
            block = False

    devices.thread.start()
    running = True
    restore_sigterm = sigterm_as_ctrl_c()
    try:
        while True:
            job = _wait_get(devices.captures, devices.ended)
            if job is None:
                break
            job.slot = _wait_get(devices.free, devices.ended)
            slot = devices.slots[job.slot]
            if maps is not None:
                _compute_on_device(job, slot, net, maps, memory_format, keep_rectified, wait)
            else:
                job.stages.start()
                rectify(job.frame, out=slot.rectified)
                if slot.copy_captured:  # a network that takes contiguous (B, 3, H, W) images: one split
                    cv2.split(slot.rectified, slot.captured_planes)
                job.frame = np.empty(0)  # used up
                job.stages.stop("rectify")
                job.stages.start()
                with torch.inference_mode():
                    if surface is None:
                        compensated = net(job.light, slot.captured)
                    else:
                        compensated = surface.compensate(net, job.light, slot.captured)
                job.stages.stop("compensate")
                job.stages.start()
                with torch.inference_mode():  # clamps to [0, 1]
                    inverse.apply(compensated.permute(0, 2, 3, 1)[0], out=slot.projector_input_t)
                job.stages.stop("to_input")
            _wait_put(devices.compensated, job, devices.stop)
            running = drain(block=False)
        _wait_put(devices.compensated, None, devices.stop)
        while running:
            running = drain(block=True)
    except KeyboardInterrupt:
        summary.interrupted = True
    except _Stopped:
        pass
    finally:
        restore_sigterm()  # a second SIGTERM while stopping ends the process
        devices.stop.set()
        devices.thread.join()
        worker.close(join_timeout_s=stall_timeout_s)
        drain(block=False)  # frames shown while stopping
    summary.wall_s = last_shown - started
    summary.stalls = devices.stalls
    if isinstance(devices.error, KeyboardInterrupt):
        summary.interrupted = True
    elif devices.error is not None:
        raise devices.error
    return summary
