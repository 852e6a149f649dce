"""The live loop on a projector: show ``I``, capture ``I*``, rectify, compensate, show ``Î``.

Spaces (docs/procams.md): the target ``I`` and the network's output are projector *output
light* per projector pixel (full primary = 1); a camera frame is linear *camera* RGB; what a
display receives is projector *input*. Per frame:

1. ``show_target``: send ``f^-1(I)`` (the inverse of the measured response) and wait until shown;
2. ``capture``: grab the camera frame ``c`` (settle delay, averaging: :func:`grab_frame`);
3. ``rectify``: ``I* = M^-1 (c(q(x)) - c_black(q(x)))`` in projector pixels
   (:meth:`ProCamsCalibration.to_output_space`);
4. ``compensate``: ``x = clamp(net(I, I*), 0, 1)``;
5. ``to_input``: ``u = f^-1(x)`` (:meth:`ProCamsCalibration.to_projector_input`);
6. ``show_compensated``: send ``u``.

With ``measure`` the compensated projection is captured and rectified too (``check``, not
counted in the frame time), and both captures are scored with SSIM against ``I``.
Ctrl-C (``KeyboardInterrupt``) ends the loop after the current stage; the summary so far is
returned.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import IMAGE_EXTENSIONS, read_image_array, to_unit_float
from ..metrics import ssim
from ..procams.calibration import ProCamsCalibration
from ..procams.devices import Camera, Display, GrabSettings, grab_frame

STAGES = ("show_target", "capture", "rectify", "compensate", "to_input", "show_compensated")


def _to_tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(image, dtype=np.float32).transpose(2, 0, 1)))[None]


def _to_array(image: torch.Tensor) -> np.ndarray:
    return image[0].detach().cpu().numpy().transpose(1, 2, 0)


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
            f"image '{path}' is {image.shape[1]}x{image.shape[0]} but the calibration was made for a "
            f"{size_hw[1]}x{size_hw[0]} projector"
        )
    return image.astype(np.float32)


def frame_source(
    size_hw: tuple[int, int], image: str | None = None, images: str | None = None, video: str | None = None
) -> Iterator[tuple[str, np.ndarray]]:
    """Target frames ``(name, (H, W, 3) in [0, 1])`` at the projector's size: one image repeated,
    a folder's images in turn (repeated), each of the projector's size (else refused), or a
    video's frames until its end (resized to the projector)."""
    if sum(x is not None for x in (image, images, video)) != 1:
        raise EdofprojError("give one of --image, --images, --video")
    if video is not None:
        if not Path(video).is_file():
            raise EdofprojError(f"video '{video}' does not exist")
        capture = cv2.VideoCapture(video)
        if not capture.isOpened():
            raise EdofprojError(f"OpenCV cannot open the video '{video}'")
        number = 0
        try:
            while True:
                ok, frame = capture.read()
                if not ok:
                    return
                yield f"{Path(video).name}#{number}", fit_to_projector(to_unit_float(frame[..., ::-1]), size_hw)
                number += 1
        finally:
            capture.release()
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


@dataclass
class LiveFrame:
    """One frame of the loop: its target, the rectified captures and the stage times (s)."""

    name: str
    target: np.ndarray
    uncompensated: np.ndarray
    compensated_input: np.ndarray
    stage_s: dict[str, float]
    compensated: np.ndarray | None = None
    ssim_uncompensated: float | None = None
    ssim_compensated: float | None = None


@dataclass
class LiveSummary:
    frames: int = 0
    interrupted: bool = False
    stage_s: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in STAGES + ("check",)})
    ssim_uncompensated: list[float] = field(default_factory=list)
    ssim_compensated: list[float] = field(default_factory=list)

    @property
    def frame_s(self) -> float:
        """Mean time of one frame (the six stages, without ``check``)."""
        return float(sum(np.mean(self.stage_s[s]) for s in STAGES)) if self.frames else float("nan")

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_s if self.frames else float("nan")

    def mean_stage_ms(self) -> dict[str, float]:
        return {s: 1e3 * float(np.mean(t)) for s, t in self.stage_s.items() if t}


def run_live(
    net: torch.nn.Module,
    calibration: ProCamsCalibration,
    display: Display,
    camera: Camera,
    targets: Iterable[tuple[str, np.ndarray]],
    grab: GrabSettings = GrabSettings(),
    frames: int | None = None,
    measure: bool = False,
    on_frame: Callable[[LiveFrame], None] | None = None,
) -> LiveSummary:
    """Run the loop (module docstring) over ``targets`` until ``frames`` frames, their end or Ctrl-C."""
    summary = LiveSummary()
    clock = time.perf_counter

    def timed(stage: str, times: dict[str, float], function, *args):
        start = clock()
        result = function(*args)
        times[stage] = clock() - start
        return result

    def show_light(light: torch.Tensor) -> np.ndarray:
        projector_input = _to_array(calibration.to_projector_input(light))
        display.show(projector_input)
        return projector_input

    calibration.to_projector_input(torch.zeros(1, 3, 1, 1))  # builds the inverse-response table outside the timing
    try:
        for name, target in targets:
            if frames is not None and summary.frames >= frames:
                break
            calibration.check_projector_hw(target.shape[:2], what=f"target '{name}'")
            times: dict[str, float] = {}
            light = _to_tensor(target)
            timed("show_target", times, show_light, light)
            frame = timed("capture", times, grab_frame, camera, grab, f"capture of '{name}'")
            rectified = timed("rectify", times, calibration.to_output_space, frame)

            def compensate() -> torch.Tensor:
                with torch.inference_mode():
                    return net(light, _to_tensor(rectified)).clamp(0.0, 1.0)

            compensated_light = timed("compensate", times, compensate)
            projector_input = timed(
                "to_input", times, lambda: _to_array(calibration.to_projector_input(compensated_light))
            )
            timed("show_compensated", times, display.show, projector_input)
            record = LiveFrame(name, target, rectified.astype(np.float32), projector_input, times)
            if measure:
                start = clock()
                compensated = calibration.to_output_space(grab_frame(camera, grab, f"check of '{name}'"))
                record.compensated = compensated.astype(np.float32)
                record.ssim_uncompensated = score_against(rectified, light)
                record.ssim_compensated = score_against(compensated, light)
                summary.ssim_uncompensated.append(record.ssim_uncompensated)
                summary.ssim_compensated.append(record.ssim_compensated)
                times["check"] = clock() - start
            summary.frames += 1
            for stage, seconds in times.items():
                summary.stage_s[stage].append(seconds)
            if on_frame is not None:
                on_frame(record)
    except KeyboardInterrupt:
        summary.interrupted = True
    return summary
