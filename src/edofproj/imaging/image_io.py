"""Reading and writing images as float tensors ``(3, H, W)`` in ``[0, 1]`` (RGB), with OpenCV.

* :func:`read_image`: PNG, JPEG, TIFF, BMP, ... with 8 or 16 bits per channel; grey images are
  repeated into three channels, an alpha channel is dropped (not composited), the EXIF
  orientation of photographs is applied. ``value / (2^bits - 1)``.
* :func:`write_image`: ``round(clamp(x, 0, 1) * (2^bits - 1))`` as 8 or 16 bits, written
  atomically (:mod:`edofproj.fileio`); the format follows the file extension.
* :func:`open_video`: a video file (or camera) opened with OpenCV, quietly.

A file that cannot be read gets one line from edofproj (:class:`~edofproj.errors.EdofprojError`)
and nothing from the libraries under it: OpenCV's log is silenced while it decodes, FFmpeg's own
log (e.g. "moov atom not found") is off (``OPENCV_FFMPEG_LOGLEVEL=-8``, AV_LOG_QUIET, set unless
the environment already sets it: OpenCV reads it once, when its FFmpeg backend first starts) and
Pillow's warnings about damaged metadata are not shown. libpng writes its own ``libpng error: ...`` and
``libpng warning: ...`` lines straight to the process's stderr (file descriptor 2), which no log
level reaches: while OpenCV decodes, descriptor 2 is sent to a temporary file, and what it received
is written back afterwards without libpng's lines (:func:`_without_libpng_lines`).

OpenCV stores colour as BGR; the conversion to and from RGB happens here and nowhere else.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import write_bytes_atomic
from ..limits import check_memory

WRITE_BITS = {".png": (8, 16), ".tif": (8, 16), ".tiff": (8, 16), ".jpg": (8,), ".jpeg": (8,), ".bmp": (8,)}
"""Output extensions and the bit depths each supports."""

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
"""Extensions of the image files the tools read (training folders, ``--images DIR``, captures)."""

JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"

#: FFmpeg's own log off (AV_LOG_QUIET) unless the environment says otherwise (module docstring).
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")


def _jpeg_is_truncated(data: bytes) -> bool:
    """True for a JPEG that stops before its end-of-image marker (OpenCV decodes those silently).

    A missing marker at the very end is confirmed with Pillow's full decode, because some
    writers append bytes after the marker.
    """
    if not data.startswith(JPEG_START) or data.rstrip(b"\x00").endswith(JPEG_END):
        return False
    from PIL import Image  # start-up: `edofproj --help` loads this module; Pillow costs ~40 ms

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. "Corrupt EXIF data": the decode decides
            with Image.open(io.BytesIO(data)) as picture:
                picture.load()
    except (OSError, SyntaxError, ValueError):
        return True
    return False


@contextlib.contextmanager
def _quiet_opencv():
    """Silence OpenCV's own log (e.g. "PNG input buffer is incomplete", a TIFF or BMP decoder's
    ERROR lines): we raise our own one-line error."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


#: The lines libpng writes to descriptor 2 itself (its default error and warning handlers).
LIBPNG_LINE_PREFIXES = (b"libpng error:", b"libpng warning:")


@contextlib.contextmanager
def _without_libpng_lines():
    """Descriptor 2 (stderr) sent to a temporary file while the block runs, then what it received
    written back less libpng's own lines (module docstring): other output is delayed, never lost."""
    import sys
    import tempfile

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no descriptor 2 (a detached process): nothing to silence
        yield
        return
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield
        finally:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            kept = [
                line for line in captured.read().splitlines(keepends=True) if not line.startswith(LIBPNG_LINE_PREFIXES)
            ]
            if kept:
                os.write(2, b"".join(kept))


#: Bytes per pixel of reading an image into a float tensor: the decoded 8/16-bit BGR pixels, their
#: RGB copy, the float32 array and the tensor (16-bit worst case: 6 + 6 + 12 + 12).
READ_BYTES_PER_PIXEL = 36


def _size_from_header(source) -> tuple[int, int] | None:
    """``(height, width)`` that Pillow reads from the header of ``source`` (a path or a binary file),
    decoding no pixels and reading no more of the file than the header, or None."""
    from PIL import Image  # start-up: `edofproj --help` loads this module; Pillow costs ~40 ms

    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None  # reading the header of a huge image is what we want here
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. "Corrupt EXIF data": OpenCV decides below
            with Image.open(source) as picture:
                width, height = picture.size
    except Exception:  # noqa: BLE001 - any header Pillow cannot read: OpenCV decides below
        return None
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    return int(height), int(width)


def image_size_from_header(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` read from the file header alone (no pixels decoded), or None."""
    return _size_from_header(io.BytesIO(data))


def image_file_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(height, width)`` of an image file from its header (None when it cannot be read): the one
    header reader of the image files every command and data source reads."""
    try:
        with open(path, "rb") as handle:
            return _size_from_header(handle)
    except OSError:
        return None


def decode_image(data: bytes, name: str = "image") -> np.ndarray:
    """Decode encoded image bytes to an RGB ``uint8`` or ``uint16`` array ``(H, W, 3)``
    (refused, before decoding, when its pixels would not fit in the memory available)."""
    size = image_size_from_header(data)
    if size is not None:
        check_memory(
            READ_BYTES_PER_PIXEL * size[0] * size[1],
            f"reading the {size[0]}x{size[1]} (height x width) image '{name}'",
            "scale the image down first",
        )
    raw = np.frombuffer(data, dtype=np.uint8)
    with _quiet_opencv(), _without_libpng_lines():
        pixels = cv2.imdecode(raw, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH) if raw.size else None
    if pixels is None or pixels.size == 0 or _jpeg_is_truncated(data):
        raise EdofprojError(f"cannot read image '{name}': not a readable PNG/JPEG/TIFF/BMP file or truncated")
    if pixels.dtype not in (np.uint8, np.uint16):
        raise EdofprojError(f"image '{name}' has {pixels.dtype} pixels; only 8- and 16-bit images are supported")
    return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)


def open_video(source: int | str | os.PathLike) -> cv2.VideoCapture:
    """``cv2.VideoCapture`` of a camera index, a video file or an image-sequence pattern, opened
    quietly (module docstring); the caller checks ``isOpened()`` and raises its own error. A video
    file is opened with FFmpeg alone: OpenCV's fallback readers print their complaints about a
    damaged file (e.g. "Unexpected list type" of its AVI parser) where no log level reaches them."""
    with _quiet_opencv():
        if isinstance(source, int):
            return cv2.VideoCapture(source)
        if Path(source).is_file():
            return cv2.VideoCapture(str(source), cv2.CAP_FFMPEG)
        return cv2.VideoCapture(str(source))


def to_unit_float(pixels: np.ndarray) -> np.ndarray:
    """Integer pixels to float32 in ``[0, 1]``: ``value / max(dtype)``."""
    return pixels.astype(np.float32) / np.float32(np.iinfo(pixels.dtype).max)


def read_image_array(path: str | os.PathLike) -> np.ndarray:
    """An image file as an RGB integer array ``(H, W, 3)`` (``uint8`` or ``uint16``)."""
    path = Path(path)
    if path.is_dir():
        raise EdofprojError(f"cannot read image '{path}': it is a directory")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise EdofprojError(f"image '{path}' does not exist") from None
    except OSError as exc:
        raise EdofprojError(f"cannot read image '{path}': {exc.strerror or exc}") from None
    return decode_image(data, str(path))


def read_image(path: str | os.PathLike) -> torch.Tensor:
    """An image file as a float32 tensor ``(3, H, W)`` in ``[0, 1]``, RGB (module docstring)."""
    pixels = to_unit_float(read_image_array(path))
    return torch.from_numpy(np.ascontiguousarray(pixels.transpose(2, 0, 1)))


def check_output_path(path: str | os.PathLike, bits: int = 8) -> None:
    """Raise unless ``path``'s extension can hold ``bits``-bit images (call before long computations)."""
    suffix = Path(path).suffix.lower()
    if suffix not in WRITE_BITS:
        raise EdofprojError(f"output '{path}' must end in one of {', '.join(WRITE_BITS)}")
    if bits not in WRITE_BITS[suffix]:
        allowed = " or ".join(str(b) for b in WRITE_BITS[suffix])
        raise EdofprojError(f"{suffix} files hold {allowed}-bit images, not {bits}-bit (use .png for 16 bits)")


def encode_image(image, bits: int = 8, suffix: str = ".png") -> bytes:
    """Encode a ``(3, H, W)`` or ``(1, H, W)`` float image in ``[0, 1]`` (clamped) to file bytes."""
    check_output_path(f"image{suffix}", bits)
    array = image.detach().cpu().numpy() if torch.is_tensor(image) else np.asarray(image)
    if array.ndim == 4 and array.shape[0] == 1:
        array = array[0]
    if array.ndim != 3 or array.shape[0] not in (1, 3):
        raise EdofprojError(f"an image to write must be (3, H, W) or (1, H, W), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise EdofprojError("refusing to write an image with NaN or infinite values")
    top = (1 << bits) - 1
    pixels: np.ndarray = np.rint(np.clip(array.astype(np.float64), 0.0, 1.0) * top).astype(
        np.uint8 if bits == 8 else np.uint16
    )
    pixels = pixels.transpose(1, 2, 0)
    pixels = pixels[..., 0] if pixels.shape[-1] == 1 else cv2.cvtColor(np.ascontiguousarray(pixels), cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(suffix, np.ascontiguousarray(pixels))
    if not ok:
        raise EdofprojError(f"OpenCV could not encode a {bits}-bit {suffix} image")
    return encoded.tobytes()


def write_image(path: str | os.PathLike, image, bits: int = 8) -> None:
    """Write a ``(3, H, W)`` float image in ``[0, 1]`` (clamped) as an 8- or 16-bit file, atomically."""
    check_output_path(path, bits)
    write_bytes_atomic(path, encode_image(image, bits, Path(path).suffix.lower()))
