"""A calibration's per-frame maps as tensors on a compute device (a GPU): rectification and the
inverse projector response in PyTorch, so that a live frame stays on the device from the camera
frame to the projector input.

The same two maps as :mod:`.frame_maps` (which applies them on the CPU with OpenCV), computed as
each is defined there:

* rectification ``o(x) = M^-1 c(q(x)) - M^-1 c_black(q(x))``: the camera frame ``(Hc, Wc, 3)``
  (8- or 16-bit counts, or float32 in ``[0, 1]``) is cast to float32 on the device and sampled at
  the camera positions ``q(x)`` by one bilinear :func:`torch.nn.functional.grid_sample` (clamped at
  the border, as OpenCV's ``BORDER_REPLICATE``; pixel centres at integer positions, so the grid is
  ``2 q / (size - 1) - 1`` with ``align_corners=True``); then ``M^-1 / full_scale`` per pixel (one
  3x3 product) less the black offset ``M^-1 c_black(q(x))``. The positions are not rounded and the
  warp is not rounded to counts, so for every frame dtype this is the direct rectification
  (:meth:`ProCamsCalibration.to_output_space` of the frame in ``[0, 1]``) to float32 rounding.
* the inverse response ``u = f^-1(clamp(o, 0, 1))``: a per-channel table
  (:class:`.frame_maps.ChannelInverseTable`) is one gather, ``u_c = T_c[round(o_c (N - 1))]``; the
  trilinear ``S^3`` table (:class:`.frame_maps.TrilinearInverseTable`) is one trilinear
  ``grid_sample`` of the table seen as a ``(1, 3, S, S, S)`` volume with ``(x, y, z) = (o_2, o_1,
  o_0)``.

Shapes: the rectified capture and the network's images are ``(1, 3, H, W)`` (any memory format);
the projector input is ``(H, W, 3)``, the layout a display takes, so that one copy brings it to
the host.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import EdofprojError
from .frame_maps import FRAME_FULL_SCALE, ChannelInverseTable, InverseTable, Rectifier, TrilinearInverseTable


class DeviceFrameMaps:
    """:class:`.frame_maps.Rectifier` and an inverse table (module docstring) on ``device``.

    ``rectify(frame (Hc, Wc, 3) on device) -> (1, 3, H, W)`` float32 output light;
    ``to_input(light (1, 3, H, W)) -> (H, W, 3)`` float32 projector input, with ``finite`` a
    one-element tensor that says whether ``light`` held only finite values (read it once the
    frame is on the host: reading it on the device would wait for the device).
    """

    def __init__(self, rectifier: Rectifier, inverse: InverseTable, device: torch.device | str) -> None:
        self.device = torch.device(device)
        self.rectifier = rectifier
        self.camera_hw, self.projector_hw = rectifier.camera_hw, rectifier.projector_hw
        Hc, Wc = self.camera_hw
        if min(Hc, Wc) < 2:
            raise EdofprojError(f"a camera frame of {Hc}x{Wc} pixels cannot be rectified (2x2 pixels at least)")
        grid = np.stack([rectifier.map_x * (2.0 / (Wc - 1)) - 1.0, rectifier.map_y * (2.0 / (Hc - 1)) - 1.0], axis=-1)
        self.grid = torch.from_numpy(grid.astype(np.float32))[None].to(self.device)  # (1, H, W, 2)
        unmix = torch.from_numpy(rectifier.unmix.astype(np.float32))
        # M^-1 / full scale, (3, 3), by the frame's torch dtype (uint8, uint16, float32)
        self.unmix_by_dtype = {
            torch.from_numpy(np.zeros(1, dtype)).dtype: (unmix / scale).to(self.device)
            for dtype, scale in FRAME_FULL_SCALE.items()
        }
        offset = torch.from_numpy(rectifier.offset).permute(2, 0, 1)[None]  # (1, 3, H, W)
        self.offset = (offset[:, :, :1, :1] if rectifier.uniform_black else offset).contiguous().to(self.device)
        self.channel_table: torch.Tensor | None = None
        self.volume: torch.Tensor | None = None
        if isinstance(inverse, ChannelInverseTable):
            self.bins = inverse.bins
            self.channel_table = torch.from_numpy(inverse.table.reshape(-1).copy()).to(self.device)  # (3 N,)
            self.row_offsets = (torch.arange(3) * self.bins).view(3, 1, 1).to(self.device)
        elif isinstance(inverse, TrilinearInverseTable):
            # T[i, j, k] (o_0, o_1, o_2) as a (1, 3, D=i, H=j, W=k) volume
            self.volume = torch.from_numpy(inverse.table).permute(3, 0, 1, 2)[None].contiguous().to(self.device)
        else:
            raise EdofprojError(f"no device form of the inverse table {type(inverse).__name__}")

    def upload(self, frame: np.ndarray, staging: torch.Tensor | None = None) -> torch.Tensor:
        """A camera frame ``(Hc, Wc, 3)`` on the device, in its own dtype (through ``staging``, a
        page-locked host tensor of its shape and dtype, when given: the copy then overlaps)."""
        self.rectifier.check_frame(frame)
        if np.dtype(frame.dtype) not in FRAME_FULL_SCALE:
            frame = frame.astype(np.float32)
        host = torch.from_numpy(np.ascontiguousarray(frame))
        if staging is not None and staging.shape == host.shape and staging.dtype == host.dtype:
            staging.copy_(host)
            host = staging
        return host.to(self.device, non_blocking=staging is not None)

    def rectify(self, frame: torch.Tensor) -> torch.Tensor:
        """``o = M^-1 frame(q(x)) / full_scale - M^-1 c_black(q(x))``, ``(Hc, Wc, 3)`` -> ``(1, 3, H, W)``."""
        unmix = self.unmix_by_dtype[frame.dtype]  # an uploaded frame is in one of these dtypes
        image = frame.permute(2, 0, 1)[None].float()  # (1, 3, Hc, Wc), counts or [0, 1]
        warped = F.grid_sample(image, self.grid, mode="bilinear", padding_mode="border", align_corners=True)
        return torch.einsum("ij,bjhw->bihw", unmix, warped) - self.offset

    def to_input(self, light: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(u (H, W, 3), finite (1,))`` for output light ``(1, 3, H, W)`` (clamped to ``[0, 1]``)."""
        light = light.detach().float()
        finite = torch.isfinite(light).all().reshape(1)
        o = torch.nan_to_num(light[0], nan=0.0).clamp(0.0, 1.0)  # (3, H, W); NaN read as 0, then refused
        if self.channel_table is not None:
            index = torch.round(o * (self.bins - 1)).long() + self.row_offsets
            u = self.channel_table[index]  # (3, H, W)
            return u.permute(1, 2, 0), finite
        assert self.volume is not None
        grid = (o.permute(1, 2, 0).flip(-1) * 2.0 - 1.0)[None, None]  # (1, 1, H, W, 3): (x, y, z) = (o_2, o_1, o_0)
        u = F.grid_sample(self.volume, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return u[0, :, 0].permute(1, 2, 0), finite  # (H, W, 3)
