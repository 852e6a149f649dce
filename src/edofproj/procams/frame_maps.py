"""A calibration's per-frame maps, computed once: rectification and the inverse projector response.

Everything in a live frame that does not change between frames is tabulated when the loop
starts, so that a frame costs the arithmetic of applying the tables and no allocation:

* :class:`Rectifier`: ``o(x) = M^-1 c(q(x)) - M^-1 c_black(q(x))`` (:mod:`.calibration`). The
  camera map ``q`` is kept as the maps :func:`cv2.remap` reads (float32, and OpenCV's fixed-point
  pair for integer frames; no conversion per frame); the frame is warped in the dtype the camera
  delivers (8- or 16-bit counts, or float32) and cast to float32 at the projector's size; the
  colour unmixing (with the scale of the counts) is one :func:`cv2.transform` (a 3x3 matrix per
  pixel), the black capture its fourth column when uniform, else one offset image
  ``M^-1 c_black(q(x))``. Bilinear warping and the per-pixel matrix commute, so this is
  :meth:`ProCamsCalibration.to_output_space` up to float32 rounding for float frames (integer
  frames: within half a count, :class:`Rectifier`).
* the inverse response ``u = f^-1(o)``:

  - :class:`ChannelInverseTable` where the measured response is **separable** (``o_c`` depends
    on ``u_c`` alone, :func:`separable_response`): per channel, the forward response through the
    colour-sample levels is interpolated by a monotone cubic (PCHIP, Fritsch & Carlson 1980),
    inverted on a dense grid and tabulated at :data:`CHANNEL_TABLE_BINS` bins of ``o`` in
    ``[0, 1]``; a pixel is one table read, ``u_c = T_c[round(o_c (N - 1))]`` (bin error
    ``|f^-1'| / (2 (N - 1))``, below an 8-bit step wherever ``|f^-1'| < 257``).
    On 6 levels of ``u^2.2`` the table is within 0.0009 of ``o^(1/2.2)`` on average (0.017 at
    most, near black where the inverse is steepest), against 0.03 for the local linear
    interpolation of :mod:`.color`, which cannot know that the channels are independent.
  - :class:`TrilinearInverseTable` otherwise: the ``S^3`` table of :class:`.color.ResponseLUT`
    read by trilinear interpolation, ``u = sum_corners w_corner T[corner]`` with
    ``w = prod_c (1 - |t_c - corner_c|)``, as two bilinear :func:`cv2.remap` reads of the table's
    slices and one linear blend.

Images in the hot path are ``(H, W, 3)`` -- the camera frame in its own dtype, everything after it
float32 -- the layout of a camera frame, of what a display takes, and of a ``channels_last``
tensor: no transposition anywhere.
"""

from __future__ import annotations

import math
import threading
from typing import Any, Callable

import cv2
import numpy as np
import torch
from scipy.interpolate import PchipInterpolator

from ..errors import EdofprojError
from .color import ColorCalibration
from .geometry import CameraMap

CHANNEL_TABLE_BINS = 65536
"""Bins of ``o`` in ``[0, 1]`` per channel of :class:`ChannelInverseTable` (768 kB in all)."""
SEPARABLE_TOLERANCE = 0.01
"""Largest spread of ``o_c`` among colour samples with the same ``u_c`` for a separable response
(output units, full primary = 1): about one 8-bit input step of a gamma-2.2 projector at full output."""
FORWARD_SAMPLES = 4097
"""Samples of the interpolated forward response per channel from which the inverse is tabulated."""


class ThreadBuffers:
    """Scratch buffers made on first use, kept per calling thread and key (a shape, a dtype).

    The live loop applies the same table in two threads at once -- its device thread for a new
    target, its compute thread for every frame -- so buffers shared between threads would be
    overwritten mid-call; per thread, each keeps its own and nothing is allocated after the first
    call."""

    def __init__(self, make: Callable[[Any], Any]) -> None:
        self._make = make
        self._local = threading.local()

    def get(self, key: Any) -> Any:
        store = self._local.__dict__.setdefault("buffers", {})
        if key not in store:
            store[key] = self._make(key)
        return store[key]

    def count(self) -> int:
        """Keys with buffers in the calling thread."""
        return len(self._local.__dict__.get("buffers", {}))


def separable_response(color: ColorCalibration) -> tuple[bool, float]:
    """``(separable, spread)``: whether ``o_c`` depends on ``u_c`` alone at the colour samples.

    ``spread`` is the largest ``|o_kc - mean_{j: u_jc = u_kc} o_jc|`` over samples ``k`` and
    channels ``c``; the response is separable when the samples repeat each level (a grid) and
    ``spread <= SEPARABLE_TOLERANCE``.
    """
    inputs, outputs = np.asarray(color.sample_inputs), np.asarray(color.sample_outputs)
    spread = 0.0
    for channel in range(3):
        levels, inverse, counts = np.unique(inputs[:, channel], return_inverse=True, return_counts=True)
        if len(levels) < 2 or counts.min() < 2:
            return False, float("inf")
        means = np.bincount(inverse, weights=outputs[:, channel]) / counts
        spread = max(spread, float(np.abs(outputs[:, channel] - means[inverse]).max()))
    return spread <= SEPARABLE_TOLERANCE, spread


class ChannelInverseTable:
    """``u_c = T_c[round(clip(o_c, 0, 1) (N - 1))]`` per channel (module docstring); ``table (3, N)``."""

    def __init__(self, table: np.ndarray) -> None:
        table = np.asarray(table, dtype=np.float32)
        if table.ndim != 2 or table.shape[0] != 3 or not 2 <= table.shape[1] <= 2**16:
            raise EdofprojError(f"a per-channel response table must be (3, N) with 2 <= N <= 65536, got {table.shape}")
        self.table = table
        self.bins = table.shape[1]
        # rows padded to 2^16 with their last value: an index saturated at 65535 reads T_c[N - 1]
        padded = np.concatenate([table, np.repeat(table[:, -1:], 2**16 - self.bins, axis=1)], axis=1)
        self._flat = torch.from_numpy(np.ascontiguousarray(padded.reshape(-1)))
        # flat index = round(o (N - 1)) + c 2^16: the nearest bin of channel c's row
        self._scale = (float(self.bins - 1),) * 4
        self._row_offsets = tuple(float(c * 2**16) for c in range(3)) + (0.0,)
        self._scratch = ThreadBuffers(self._make_buffers)

    @staticmethod
    def _make_buffers(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, torch.Tensor, np.ndarray]:
        """The bins (uint16), the flat indices (int32, and as a tensor) and an interleaving buffer."""
        index_i32 = np.empty(shape, np.int32)
        return np.empty(shape, np.uint16), index_i32, torch.from_numpy(index_i32), np.empty(shape, np.float32)

    @classmethod
    def from_color(cls, color: ColorCalibration, bins: int = CHANNEL_TABLE_BINS) -> "ChannelInverseTable":
        """The table of a separable response (:func:`separable_response`) from its colour samples."""
        inputs, outputs = np.asarray(color.sample_inputs), np.asarray(color.sample_outputs)
        u = np.linspace(0.0, 1.0, FORWARD_SAMPLES)
        o_bins = np.linspace(0.0, 1.0, bins)
        rows = []
        for channel in range(3):
            levels, inverse, counts = np.unique(inputs[:, channel], return_inverse=True, return_counts=True)
            means = np.bincount(inverse, weights=outputs[:, channel]) / counts
            forward = np.maximum.accumulate(PchipInterpolator(levels, np.maximum.accumulate(means))(u))
            # np.interp needs increasing abscissae: flat stretches of the forward curve keep their first input
            keep = np.r_[True, np.diff(forward) > 0]
            rows.append(np.clip(np.interp(o_bins, forward[keep], u[keep]), 0.0, 1.0))
        return cls(np.stack(rows))

    def apply(self, light: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """``u`` for ``light (..., 3)`` float32 (clamped to ``[0, 1]``), written into ``out`` (same
        shape, float32; allocated when None).

        Three passes over the pixels, in buffers kept per shape: the bin, ``round(o (N - 1))``
        saturated to ``[0, 65535]`` (one :func:`cv2.multiply` into ``uint16``: the clamp, the scale
        and the rounding at once; the rows are padded to ``2^16`` with their last value, so a bin
        above ``N - 1`` reads ``T_c[N - 1]``); the row offset ``c 2^16`` (one :func:`cv2.add` into
        ``int32``); the table read (one :func:`torch.index_select` of the flat table). NaN and
        infinities are refused (one sum).
        """
        shape = tuple(light.shape)
        if shape[-1] != 3:
            raise EdofprojError(f"a colour table takes (..., 3) images, got {shape}")
        if not math.isfinite(float(light.detach().sum())):
            raise EdofprojError("the projector output light holds NaN or infinite values")
        index_u16, index_i32, index_t, interleaved = self._scratch.get(shape)
        pixels = _as_pixels(interleaved_pixels(light, interleaved))
        # a tuple is an OpenCV Scalar (one value per channel), valid but missing from its stubs
        cv2.multiply(pixels, self._scale, dst=_as_pixels(index_u16), dtype=cv2.CV_16U)  # type: ignore[call-overload]
        cv2.add(_as_pixels(index_u16), self._row_offsets, dst=_as_pixels(index_i32), dtype=cv2.CV_32S)  # type: ignore[call-overload]
        if out is None:
            out = torch.empty(shape)
        target = out if out.is_contiguous() else torch.empty(shape)
        torch.index_select(self._flat, 0, index_t.view(-1), out=target.view(-1))
        if target is not out:
            out.copy_(target)
        return out


def interleaved_pixels(light: torch.Tensor, scratch: np.ndarray) -> np.ndarray:
    """``light (..., 3)`` as a contiguous float32 NumPy array: itself when it is one (no copy);
    the planes of a channel-first tensor seen as ``(..., H, W, 3)`` (a network's contiguous
    ``(B, 3, H, W)`` output, permuted) interleaved into ``scratch`` by :func:`cv2.merge` (about 4x
    faster than a strided copy); anything else copied into ``scratch``."""
    light = light.detach()
    if light.dtype == torch.float32 and light.is_contiguous():
        return light.numpy()
    planar = light.movedim(-1, -3)
    if light.dtype == torch.float32 and light.dim() >= 3 and planar.is_contiguous():
        H, W = light.shape[-3:-1]
        images = scratch.reshape(-1, H, W, 3)
        for image, planes in zip(images, planar.reshape(-1, 3, H, W).numpy()):
            cv2.merge(list(planes), image)
        return scratch
    torch.from_numpy(scratch).copy_(light)
    return scratch


def _as_pixels(array: np.ndarray) -> np.ndarray:
    """A contiguous ``(..., 3)`` array viewed as OpenCV's ``(n, 1)`` 3-channel image (no copy), so
    that per-channel scalars apply to the channels whatever the leading shape."""
    return array.reshape(-1, 1, 3)


class TrilinearInverseTable:
    """Trilinear reading of an ``(S, S, S, 3)`` table ``T[i, j, k]`` over ``[0, 1]^3`` (module docstring).

    With ``t = clip(o, 0, 1) (S - 1)`` and ``l_0 = min(floor(t_0), S - 2)``, ``f_0 = t_0 - l_0``,
    trilinear interpolation is the linear blend along channel 0 of two bilinear reads in the
    ``(j, k)`` slices ``l_0`` and ``l_0 + 1``. The slices are laid side by side as one
    ``(S, S * S)`` three-channel image ``T2[j, i S + k] = T[i, j, k]``, so each bilinear read is
    one :func:`cv2.remap` at ``(x, y) = (l_0 S + t_2, t_1)`` (then ``x + S``), and the blend is one
    :func:`torch.lerp`: two remaps instead of eight row gathers. Every buffer is kept per shape
    (and thread: :class:`ThreadBuffers`).

    Precision: the position ``x`` is a float32 below ``S^2``, rounded by at most ``S^2 2^-24``
    table cells (2.5e-4 cells for ``S = 65``); the result is within :attr:`tolerance` (that times
    the table's largest step between neighbouring entries, plus float32 rounding) of exact
    trilinear interpolation.
    """

    def __init__(self, table: np.ndarray) -> None:
        table = np.asarray(table, dtype=np.float32)
        if table.ndim != 4 or table.shape[-1] != 3 or len(set(table.shape[:3])) != 1 or table.shape[0] < 2:
            raise EdofprojError(f"a response table must be (S, S, S, 3) with S >= 2, got {table.shape}")
        self.table = table
        self.size = S = table.shape[0]
        self._slices = np.ascontiguousarray(table.transpose(1, 0, 2, 3).reshape(S, S * S, 3))
        largest_step = max(float(np.abs(np.diff(table, axis=axis)).max()) for axis in range(3))
        self.tolerance = S * S * 2.0**-24 * largest_step + 1e-6
        self._scratch = ThreadBuffers(self._make_buffers)

    @staticmethod
    def _make_buffers(height_width: tuple[int, int]) -> dict[str, np.ndarray]:
        planes = {name: np.empty(height_width, np.float32) for name in ("t0", "t1", "t2", "low", "x")}
        names = ("t", "near", "far", "weight", "interleaved")
        return planes | {name: np.empty(height_width + (3,), np.float32) for name in names}

    def apply(self, light: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """``u`` for ``light (..., 3)`` (clamped to ``[0, 1]``) into ``out`` (same shape; allocated when None)."""
        shape = tuple(light.shape)
        if shape[-1] != 3:
            raise EdofprojError(f"a colour table takes (..., 3) images, got {shape}")
        if not math.isfinite(float(light.detach().sum())):
            raise EdofprojError("the projector output light holds NaN or infinite values")
        S = self.size
        height_width = (math.prod(shape[:-2]), shape[-2]) if len(shape) >= 3 else (math.prod(shape[:-1]), 1)
        b = self._scratch.get(height_width)
        pixels = interleaved_pixels(light, b["interleaved"].reshape(shape)).reshape(height_width + (3,))
        np.clip(pixels, 0.0, 1.0, out=b["t"])
        np.multiply(b["t"], S - 1, out=b["t"])
        cv2.split(b["t"], [b["t0"], b["t1"], b["t2"]])
        np.floor(b["t0"], out=b["low"])
        np.minimum(b["low"], S - 2, out=b["low"])
        np.subtract(b["t0"], b["low"], out=b["t0"])  # f_0
        np.multiply(b["low"], S, out=b["x"])
        np.add(b["x"], b["t2"], out=b["x"])  # l_0 S + t_2
        cv2.remap(self._slices, b["x"], b["t1"], cv2.INTER_LINEAR, dst=b["near"], borderMode=cv2.BORDER_REPLICATE)
        np.add(b["x"], S, out=b["x"])
        cv2.remap(self._slices, b["x"], b["t1"], cv2.INTER_LINEAR, dst=b["far"], borderMode=cv2.BORDER_REPLICATE)
        cv2.merge([b["t0"], b["t0"], b["t0"]], b["weight"])
        if out is None:
            out = torch.empty(shape)
        target = out if out.is_contiguous() else torch.empty(shape)
        near, far, weight = (torch.from_numpy(b[name]) for name in ("near", "far", "weight"))
        torch.lerp(near, far, weight, out=target.view(height_width + (3,)))
        if target is not out:
            out.copy_(target)
        return out


InverseTable = ChannelInverseTable | TrilinearInverseTable


def inverse_response_table(color: ColorCalibration, lut_size: int) -> InverseTable:
    """The per-channel table where the response is separable, else the trilinear ``lut_size^3`` one."""
    if separable_response(color)[0]:
        return ChannelInverseTable.from_color(color)
    return TrilinearInverseTable(color.inverse_response_lut(lut_size).table)


MAP_STEPS_PER_PIXEL = 32
"""Sub-pixel steps of OpenCV's fixed-point maps (``INTER_TAB_SIZE``): positions of integer frames."""
FRAME_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0, np.dtype(np.float32): 1.0}
"""Camera frame dtypes the rectifier warps as they come, and the value of full scale in each."""


class Rectifier:
    """A camera frame ``(Hc, Wc, 3)`` -> projector output light ``(H, W, 3)`` float32 (module
    docstring), into a buffer the caller owns.

    The frame is warped in the dtype the camera delivers (:data:`FRAME_FULL_SCALE`: ``uint8`` or
    ``uint16`` counts, or float32 in ``[0, 1]``; another dtype is converted to float32 first):
    the warp is the only pass over the camera's resolution, and an 8-bit frame moves a quarter of
    the bytes of a float one. Only at the projector's resolution is it turned into float32 (one
    cast into ``out``), and one in-place :func:`cv2.transform` applies ``M^-1 / full_scale`` --
    with the black offset as its fourth column when the black image is uniform (the same offset at
    every pixel), else one subtraction of the offset image follows.

    Precision: integer frames are warped with OpenCV's fixed-point maps (:func:`cv2.convertMaps`,
    made once; float maps would be converted at every call, 2 ms at 600x800): the camera position
    ``q(x)`` is rounded to 1/32 pixel (:data:`MAP_STEPS_PER_PIXEL`; a camera map is measured to
    about 0.1 camera pixel, so this adds nothing one could see) and the warp rounds its result to
    the nearest count. An integer frame's rectification is therefore the direct one at the rounded
    positions to within half a count per channel through the unmixing, ``||M^-1||_inf 0.5 /
    full_scale`` (:meth:`integer_warp_tolerance`). Float frames are warped with the float maps.

    (OpenCV warps 4-channel float images with vector code, about 3x faster than 3-channel ones,
    but giving the frame a fourth channel costs as much as it saves: measured, the same CPU time.)
    """

    def __init__(self, camera_map: CameraMap, color: ColorCalibration, black_image: np.ndarray) -> None:
        self.camera_hw = tuple(camera_map.camera_hw)
        self.projector_hw = tuple(camera_map.projector_hw)
        self.map_x = np.ascontiguousarray(camera_map.map_x, dtype=np.float32)
        self.map_y = np.ascontiguousarray(camera_map.map_y, dtype=np.float32)
        unmix = np.linalg.inv(color.mixing_matrix)
        self.unmix = unmix.astype(np.float32)
        offset = np.asarray(black_image, dtype=np.float64) @ unmix.T
        self.offset = np.ascontiguousarray(offset, dtype=np.float32)
        flat_offset = self.offset.reshape(-1, 3)
        self.uniform_black = bool(np.all(flat_offset == flat_offset[:1]))
        # per dtype: M^-1 / full scale, and the uniform offset as the 4th column (or none)
        self._matrices = {
            dtype: np.ascontiguousarray(
                np.concatenate([unmix / scale, -offset.reshape(-1, 3)[:1].T], axis=1)
                if self.uniform_black
                else unmix / scale,
                dtype=np.float32,
            )
            for dtype, scale in FRAME_FULL_SCALE.items()
        }
        fixed_map, fixed_fraction = cv2.convertMaps(self.map_x, self.map_y, cv2.CV_16SC2)
        self.fixed_map, self.fixed_fraction = np.asarray(fixed_map), np.asarray(fixed_fraction)
        self._warped = ThreadBuffers(lambda dtype: np.empty(self.projector_hw + (3,), dtype))

    def integer_warp_tolerance(self, dtype: np.dtype) -> float:
        """Largest difference between the rectification of ``dtype`` counts and the direct
        rectification of the same counts at the positions rounded to 1/32 pixel, output units
        (class docstring)."""
        return float(np.abs(self.unmix).sum(axis=1).max()) * 0.5 / FRAME_FULL_SCALE[np.dtype(dtype)]

    def check_frame(self, frame: np.ndarray, what: str = "camera frame") -> None:
        """Raise one line unless ``frame`` is ``(Hc, Wc, 3)`` of the calibrated camera."""
        Hc, Wc = self.camera_hw
        if frame.ndim != 3 or frame.shape != (Hc, Wc, 3):
            size = f"{frame.shape[0]}x{frame.shape[1]}" if frame.ndim >= 2 else str(frame.shape)
            raise EdofprojError(f"{what} is {size} pixels, the calibrated camera {Hc}x{Wc} (height x width)")

    def __call__(self, frame: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``o = M^-1 frame(q(x)) - M^-1 c_black(q(x))`` into ``out`` ``(H, W, 3)`` float32."""
        self.check_frame(frame)
        if frame.dtype not in FRAME_FULL_SCALE:
            frame = frame.astype(np.float32)
        if out is None:
            out = np.empty(self.projector_hw + (3,), np.float32)
        elif out.shape != self.projector_hw + (3,) or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise EdofprojError(
                f"a rectified frame is written into a contiguous {self.projector_hw + (3,)} float32 array"
            )
        map_1: np.ndarray
        map_2: np.ndarray
        if frame.dtype == np.float32:
            map_1, map_2, warped = self.map_x, self.map_y, out
        else:  # (H, W, 2) int16 positions and (H, W) uint16 sub-pixel table indices
            map_1, map_2, warped = self.fixed_map, self.fixed_fraction, self._warped.get(frame.dtype)
        cv2.remap(
            np.ascontiguousarray(frame), map_1, map_2, cv2.INTER_LINEAR, dst=warped, borderMode=cv2.BORDER_REPLICATE
        )
        if warped is not out:
            np.copyto(out, warped)  # the cast, at the projector's resolution
        cv2.transform(out, self._matrices[frame.dtype], dst=out)
        if not self.uniform_black:
            cv2.subtract(out, self.offset, dst=out)
        return out
