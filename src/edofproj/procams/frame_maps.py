"""A calibration's per-frame maps, computed once: rectification and the inverse projector response.

Everything in a live frame that does not change between frames is tabulated when the loop
starts, so that a frame costs the arithmetic of applying the tables and no allocation:

* :class:`Rectifier`: ``o(x) = M^-1 c(q(x)) - M^-1 c_black(q(x))`` (:mod:`.calibration`). The
  camera map ``q`` is kept as the two ``float32`` maps :func:`cv2.remap` reads (no conversion per
  frame); the black capture is folded into one offset image ``M^-1 c_black(q(x))``; the colour
  unmixing is one :func:`cv2.transform` (a 3x3 matrix per pixel) of the warped frame. Bilinear
  warping and the per-pixel matrix commute, so this is :meth:`ProCamsCalibration.to_output_space`
  up to float32 rounding.
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
    ``w = prod_c (1 - |t_c - corner_c|)``, as eight row gathers.

Images in the hot path are ``(H, W, 3)`` float32, the layout of a camera frame, of what a display
takes, and of a ``channels_last`` tensor: no transposition anywhere.
"""

from __future__ import annotations

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
        if table.ndim != 2 or table.shape[0] != 3 or table.shape[1] < 2:
            raise EdofprojError(f"a per-channel response table must be (3, N), got {table.shape}")
        self.table = table
        self.bins = table.shape[1]
        self._flat = torch.from_numpy(np.ascontiguousarray(table.reshape(-1)))
        # index = o (N - 1) + 0.5 + c N, truncated: the nearest bin of channel c's row
        self._offsets = torch.tensor([0.5 + c * self.bins for c in range(3)], dtype=torch.float32)
        self._scratch: dict[tuple[int, ...], tuple[torch.Tensor, torch.Tensor]] = {}

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
        shape, float32; allocated when None). Reuses one scratch pair per shape."""
        shape = tuple(light.shape)
        if shape[-1] != 3:
            raise EdofprojError(f"a colour table takes (..., 3) images, got {shape}")
        if shape not in self._scratch:
            self._scratch[shape] = (torch.empty(shape), torch.empty(shape, dtype=torch.int32))
        scaled, index = self._scratch[shape]
        torch.clamp(light, 0.0, 1.0, out=scaled)  # (a scalar clamp first: cheaper than per-channel bounds after)
        torch.add(self._offsets, scaled, alpha=self.bins - 1, out=scaled)
        index.copy_(scaled)
        if out is None:
            out = torch.empty(shape)
        try:
            torch.index_select(self._flat, 0, index.view(-1), out=out.view(-1))
        except (IndexError, RuntimeError):
            raise EdofprojError("the projector output light holds NaN or values outside [0, 1]") from None
        return out


class TrilinearInverseTable:
    """Trilinear reading of an ``(S, S, S, 3)`` table over ``[0, 1]^3`` (module docstring)."""

    def __init__(self, table: np.ndarray) -> None:
        table = np.asarray(table, dtype=np.float32)
        if table.ndim != 4 or table.shape[-1] != 3 or len(set(table.shape[:3])) != 1:
            raise EdofprojError(f"a response table must be (S, S, S, 3), got {table.shape}")
        self.table = table
        self.size = table.shape[0]
        self._rows = torch.from_numpy(np.ascontiguousarray(table.reshape(-1, 3)))
        S = self.size
        self._strides = torch.tensor([S * S, S, 1], dtype=torch.int64)
        self._corners = [((i, j, k), i * S * S + j * S + k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]

    def apply(self, light: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """``u`` for ``light (..., 3)`` in ``[0, 1]`` into ``out`` (same shape; allocated when None)."""
        shape = tuple(light.shape)
        flat = light.reshape(-1, 3).clamp(0.0, 1.0) * (self.size - 1)
        low = flat.floor().clamp_(max=self.size - 2)
        frac = flat - low
        base = (low.long() * self._strides).sum(dim=1)
        result = torch.zeros_like(flat)
        for corner, offset in self._corners:
            weight = torch.ones(len(flat))
            for channel, side in enumerate(corner):
                weight *= frac[:, channel] if side else 1.0 - frac[:, channel]
            result.addcmul_(self._rows.index_select(0, base + offset), weight[:, None])
        if out is None:
            return result.reshape(shape)
        out.copy_(result.reshape(shape))
        return out


InverseTable = ChannelInverseTable | TrilinearInverseTable


def inverse_response_table(color: ColorCalibration, lut_size: int) -> InverseTable:
    """The per-channel table where the response is separable, else the trilinear ``lut_size^3`` one."""
    if separable_response(color)[0]:
        return ChannelInverseTable.from_color(color)
    return TrilinearInverseTable(color.inverse_response_lut(lut_size).table)


class Rectifier:
    """A camera frame ``(Hc, Wc, 3)`` float32 -> projector output light ``(H, W, 3)`` float32
    (module docstring), into a buffer the caller owns.

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
        self.offset = np.ascontiguousarray(np.asarray(black_image, dtype=np.float64) @ unmix.T, dtype=np.float32)
        self._warped = np.empty(self.projector_hw + (3,), np.float32)

    def check_frame(self, frame: np.ndarray, what: str = "camera frame") -> None:
        """Raise one line unless ``frame`` is ``(Hc, Wc, 3)`` of the calibrated camera."""
        Hc, Wc = self.camera_hw
        if frame.ndim != 3 or frame.shape != (Hc, Wc, 3):
            size = f"{frame.shape[1]}x{frame.shape[0]}" if frame.ndim >= 2 else str(frame.shape)
            raise EdofprojError(f"{what} is {size} pixels, the calibrated camera {Wc}x{Hc}")

    def __call__(self, frame: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``o = M^-1 frame(q(x)) - M^-1 c_black(q(x))`` into ``out`` ``(H, W, 3)`` float32."""
        self.check_frame(frame)
        if out is None:
            out = np.empty(self.projector_hw + (3,), np.float32)
        cv2.remap(
            np.asarray(frame, dtype=np.float32),
            self.map_x,
            self.map_y,
            cv2.INTER_LINEAR,
            dst=self._warped,
            borderMode=cv2.BORDER_REPLICATE,
        )
        cv2.transform(self._warped, self.unmix, dst=out)
        cv2.subtract(out, self.offset, dst=out)
        return out
