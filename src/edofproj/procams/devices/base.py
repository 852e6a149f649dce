"""The two device interfaces of a projector-camera session, and grabbing a frame with them.

* :class:`Display` shows a projector **input** image ``u`` (``(H, W, 3)``, values in ``[0, 1]``,
  quantized to the projector's 8 bits) and returns once it is on screen;
  :attr:`Display.shown` is the image on screen now (what a virtual camera sees).
* :class:`Camera` grabs one **linear camera** frame ``c`` (``(Hc, Wc, 3)`` float32 in ``[0, 1]``,
  RGB; a RAW or linear capture -- a camera's tone curve must be switched off or undone);
  :meth:`Camera.grab_native` gives the same frame in the dtype the sensor delivers (``uint8`` or
  ``uint16`` counts, full scale = 1), which the live loop warps without converting it first.

:func:`grab_frame` adds what every backend shares: a settle delay after the display changed,
the mean of ``N`` frames (sensor noise drops as ``1/sqrt(N)``) and one warning giving the
fraction of saturated pixels. Devices are context managers: ``with open_camera(...) as camera``.
"""

from __future__ import annotations

import abc
import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ...errors import EdofprojError
from ...imaging.image_io import to_unit_float
from ..capture_io import SATURATION_LEVEL, saturated_fraction

SATURATION_WARN_FRACTION = 1e-3
"""Warn when more than this fraction of a frame's pixels is saturated."""


def quantize_8bit(image: np.ndarray) -> np.ndarray:
    """``round(255 clip(u, 0, 1)) / 255`` as float32 ``(H, W, 3)``: what an 8-bit projector can show."""
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise EdofprojError(f"a display shows (H, W, 3) RGB images, got shape {image.shape}")
    # one sum decides for finite images (the per-pixel test only when the sum is not finite)
    if not np.isfinite(image.sum()) and not np.all(np.isfinite(image)):
        raise EdofprojError("refusing to show an image with NaN or infinite values")
    frame = np.clip(image, 0.0, 1.0)  # the one new array; then in place (a shown frame is kept)
    frame *= np.float32(255.0)
    np.rint(frame, out=frame)
    frame /= np.float32(255.0)
    return frame


class Display(abc.ABC):
    """Shows projector input images full-screen (module docstring)."""

    spec: str = ""

    def __init__(self) -> None:
        self._shown: np.ndarray | None = None

    @property
    def shown(self) -> np.ndarray | None:
        """The image on screen now, ``(H, W, 3)`` float32 in 8-bit steps, or None before the first."""
        return self._shown

    @property
    def size_hw(self) -> tuple[int, int] | None:
        """The screen's ``(height, width)`` when the backend has a fixed one, else None."""
        return None

    def show(self, image: np.ndarray) -> None:
        """Show ``image`` (projector input, ``(H, W, 3)`` in ``[0, 1]``); returns once it is on screen."""
        frame = quantize_8bit(image)
        size = self.size_hw
        if size is not None and frame.shape[:2] != tuple(size):
            raise EdofprojError(
                f"image is {frame.shape[0]}x{frame.shape[1]} but display '{self.spec}' is {size[0]}x{size[1]} (height x width) "
                "(make the patterns at the projector's native size)"
            )
        self._present(frame)
        self._shown = frame

    @abc.abstractmethod
    def _present(self, frame: np.ndarray) -> None:
        """Put ``frame`` on screen (or wherever the backend shows it)."""

    def close(self) -> None:
        """Release the screen or window."""

    def settings(self) -> dict:
        return {"spec": self.spec}

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Camera(abc.ABC):
    """Grabs linear camera frames (module docstring)."""

    spec: str = ""

    @abc.abstractmethod
    def grab(self) -> np.ndarray:
        """One frame ``(Hc, Wc, 3)`` float32 in ``[0, 1]``, linear RGB."""

    def grab_native(self) -> np.ndarray:
        """One frame in the sensor's own dtype: ``uint8`` / ``uint16`` counts (``value / max(dtype)``
        is :meth:`grab`'s) or float32 in ``[0, 1]``. Backends that decode integer frames override it;
        by default :meth:`grab`."""
        return self.grab()

    def close(self) -> None:
        """Release the camera."""

    def settings(self) -> dict:
        """What a capture log records about this camera (backend, source, exposure, ...)."""
        return {"spec": self.spec}

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class GrabSettings:
    """``settle_s``: wait after the display changed; ``average``: frames averaged per capture."""

    settle_s: float = 0.0
    average: int = 1

    def __post_init__(self) -> None:
        if not (np.isfinite(self.settle_s) and self.settle_s >= 0):
            raise EdofprojError(f"--settle-s {self.settle_s} must be >= 0")
        if self.average < 1:
            raise EdofprojError(f"--average {self.average} must be >= 1")


NATIVE_FRAME_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32))
"""Frame dtypes :func:`grab_frame` hands on as they come with ``native=True``."""


def grab_frame(
    camera: Camera,
    settings: GrabSettings = GrabSettings(),
    what: str = "capture",
    warn: bool = True,
    native: bool = False,
) -> np.ndarray:
    """The mean of ``settings.average`` frames after ``settings.settle_s``, float32 in ``[0, 1]``;
    warns (unless ``warn`` is False) when more than :data:`SATURATION_WARN_FRACTION` of a frame's
    pixels are saturated. With ``native`` and one frame, the frame of :meth:`Camera.grab_native`
    as it comes (``uint8``/``uint16`` counts or float32: :data:`NATIVE_FRAME_DTYPES`; the live loop).

    Every frame must have the first one's size (a camera that changes resolution is an error).
    """
    if settings.settle_s > 0:
        time.sleep(settings.settle_s)
    if settings.average == 1:  # the live loop's case: the frame itself, no copy
        frame = np.asarray(camera.grab_native() if native else camera.grab())
        if not (native and frame.dtype in NATIVE_FRAME_DTYPES):
            frame = to_unit_float(frame) if frame.dtype.kind in "ui" else np.asarray(frame, dtype=np.float32)
        if frame.ndim != 3 or frame.shape[-1] != 3:
            raise EdofprojError(f"camera '{camera.spec}' returned a frame of shape {frame.shape}, not (H, W, 3)")
        if warn:
            _warn_if_saturated(frame, what)
        return frame
    total: np.ndarray | None = None
    saturated = 0.0
    for _ in range(settings.average):
        frame = np.asarray(camera.grab(), dtype=np.float32)
        if frame.ndim != 3 or frame.shape[-1] != 3:
            raise EdofprojError(f"camera '{camera.spec}' returned a frame of shape {frame.shape}, not (H, W, 3)")
        if total is None:
            total = frame.astype(np.float64)
        elif frame.shape != total.shape:
            raise EdofprojError(f"camera '{camera.spec}' changed its frame size from {total.shape} to {frame.shape}")
        else:
            total += frame
        saturated = max(saturated, saturated_fraction(frame))
    if warn and saturated > SATURATION_WARN_FRACTION:
        _saturation_warning(what, saturated)
    assert total is not None
    return (total / settings.average).astype(np.float32)


def _saturation_warning(what: str, fraction: float) -> None:
    warnings.warn(
        f"{what}: {100 * fraction:.1f} % of the pixels are saturated (light there is not measured; lower the exposure)",
        stacklevel=3,
    )


def _warn_if_saturated(frame: np.ndarray, what: str) -> None:
    """The saturation warning of :func:`grab_frame` for one frame (float, or integer counts whose top
    is ``max(dtype)``); the fraction is counted only when the frame's maximum reaches the top value
    (one reduction per frame, no allocation, otherwise)."""
    integer = frame.dtype.kind in "ui"  # counts at or above SATURATION_LEVEL of full scale
    top = math.ceil(SATURATION_LEVEL * np.iinfo(frame.dtype).max) if integer else SATURATION_LEVEL
    if frame.size and frame.max() >= top:
        fraction = saturated_fraction(to_unit_float(frame) if integer else frame)
        if fraction > SATURATION_WARN_FRACTION:
            _saturation_warning(what, fraction)
