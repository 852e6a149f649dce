"""A projector-camera calibration: geometric map + colour calibration, and its ``calib.npz`` file.

:func:`calibrate` (or :func:`calibrate_folders`) runs :mod:`.geometry` on the dot grid, warps
the black, primary, white and colour-sample captures into projector pixels, warns about
saturated ones and runs :mod:`.color` on them.
:meth:`ProCamsCalibration.to_output_space` then turns any capture into projector output
light per projector pixel, ``o(x) = M^-1 (c(q(x)) - c_black(q(x)))``, which is what the PSF acts on.

``calib.npz`` keys: ``format`` (``"edofproj-procams-calibration"``), ``projector_hw``,
``camera_hw``, ``map_x``, ``map_y`` (camera coordinates of every projector pixel), ``homography``,
``dots_proj``, ``dots_cam``, ``mixing_matrix``, ``black_level`` (3,), ``black_image`` (the black
capture in projector pixels, ``(H, W, 3)``), ``color_inputs``, ``color_outputs`` (``(N, 3)``,
the colour-sample table) and ``neighbours``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import save_npz_atomic
from .capture_io import read_captures, saturated_fraction
from .color import RESPONSE_LUT_SIZE, ColorCalibration, calibrate_color
from .frame_maps import InverseTable, Rectifier, inverse_response_table
from .geometry import CameraMap, calibrate_geometry
from .patterns import PRIMARY_COLORS, PatternEntry, PatternManifest

CALIBRATION_FORMAT = "edofproj-procams-calibration"


def warn_if_saturated(captures: dict[str, np.ndarray], threshold: float = 1e-3) -> None:
    """One warning naming the captures with more than ``threshold`` saturated pixels, worst first."""
    fractions = {name: saturated_fraction(image) for name, image in captures.items()}
    saturated = sorted(((f, n) for n, f in fractions.items() if f > threshold), reverse=True)
    if saturated:
        worst_fraction, worst = saturated[0]
        warnings.warn(
            f"{len(saturated)} of {len(captures)} captures have saturated pixels (worst '{worst}': "
            f"{100 * worst_fraction:.1f} % of its pixels); saturated light is not measured -- lower the exposure",
            stacklevel=2,
        )


@dataclass
class ProCamsCalibration:
    """Geometric map, colour calibration and the black capture in projector pixels."""

    camera_map: CameraMap
    color: ColorCalibration
    black_image: np.ndarray
    response_lut_size: int = field(default=RESPONSE_LUT_SIZE, compare=False)
    _inverse_table: InverseTable | None = field(default=None, init=False, repr=False, compare=False)
    _rectifier: Rectifier | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def projector_hw(self) -> tuple[int, int]:
        return self.camera_map.projector_hw

    def to_output_space(self, capture: np.ndarray) -> np.ndarray:
        """A camera capture as projector output light per projector pixel, ``(H, W, 3)`` float64."""
        return self.color.camera_to_output(self.camera_map.warp(capture), self.black_image)

    def check_projector_hw(self, height_width: tuple[int, ...], what: str = "the image") -> None:
        """Raise one line unless ``height_width`` is the calibrated projector's size."""
        H, W = self.projector_hw
        if tuple(height_width) != (H, W):
            raise EdofprojError(
                f"{what} is {height_width[1]}x{height_width[0]} but the calibration was made for a {W}x{H} projector"
            )

    @property
    def rectifier(self) -> Rectifier:
        """The per-frame rectification (:class:`.frame_maps.Rectifier`), built on first use."""
        if self._rectifier is None:
            self._rectifier = Rectifier(self.camera_map, self.color, self.black_image)
        return self._rectifier

    @property
    def inverse_table(self) -> InverseTable:
        """The inverse response as a table (:func:`.frame_maps.inverse_response_table`: per channel
        where the response is separable, else trilinear on ``response_lut_size^3``), built on first use."""
        if self._inverse_table is None:
            self._inverse_table = inverse_response_table(self.color, self.response_lut_size)
        return self._inverse_table

    def to_projector_input(self, light: torch.Tensor) -> torch.Tensor:
        """Projector output light ``(B, 3, H, W)`` (clamped to ``[0, 1]``) -> the projector input
        that emits it, ``u = f^-1(o)`` (:attr:`inverse_table`)."""
        hwc = light.detach().float().clamp(0.0, 1.0).permute(0, 2, 3, 1).contiguous()
        return self.inverse_table.apply(hwc).permute(0, 3, 1, 2).to(light.dtype)

    def save(self, path: str | Path) -> None:
        cm, color = self.camera_map, self.color
        save_npz_atomic(
            path,
            format=np.array(CALIBRATION_FORMAT),
            projector_hw=np.array(cm.projector_hw),
            camera_hw=np.array(cm.camera_hw),
            map_x=cm.map_x.astype(np.float32),
            map_y=cm.map_y.astype(np.float32),
            homography=cm.homography,
            dots_proj=cm.dots_proj,
            dots_cam=cm.dots_cam,
            mixing_matrix=color.mixing_matrix,
            black_level=color.black_level,
            black_image=self.black_image.astype(np.float32),
            color_inputs=color.sample_inputs,
            color_outputs=color.sample_outputs,
            neighbours=np.array(color.neighbours),
        )

    @classmethod
    def load(cls, path: str | Path) -> "ProCamsCalibration":
        try:
            data = np.load(path, allow_pickle=False)
            if "format" not in data or str(data["format"]) != CALIBRATION_FORMAT:
                raise ValueError("not a calibration file (make one with 'edofproj procams calibrate')")
            camera_map = CameraMap(
                map_x=data["map_x"].astype(np.float64),
                map_y=data["map_y"].astype(np.float64),
                homography=data["homography"],
                dots_proj=data["dots_proj"],
                dots_cam=data["dots_cam"],
                camera_hw=_camera_hw(data["camera_hw"]),
            )
            color = ColorCalibration(
                mixing_matrix=data["mixing_matrix"],
                black_level=data["black_level"],
                sample_inputs=data["color_inputs"],
                sample_outputs=data["color_outputs"],
                neighbours=int(data["neighbours"]),
            )
            black = data["black_image"].astype(np.float64)
        except FileNotFoundError:
            raise EdofprojError(f"calibration file '{path}' does not exist") from None
        except (OSError, ValueError, KeyError) as exc:
            raise EdofprojError(f"cannot read calibration file '{path}': {exc}") from None
        return cls(camera_map=camera_map, color=color, black_image=black)


def _camera_hw(values: np.ndarray) -> tuple[int, int]:
    """The stored camera size ``[Hc, Wc]`` (ValueError unless it has two values)."""
    height, width = (int(v) for v in values)
    return height, width


def _sample_color(entry: PatternEntry) -> tuple[float, float, float]:
    if entry.color is None:
        raise EdofprojError(f"the pattern manifest gives no colour for colour sample '{entry.file}'")
    return entry.color


def calibration_files(manifest: PatternManifest) -> list[str]:
    """The pattern (and capture) files calibration needs: dots, black, primaries, white (the
    brightest field: only checked for saturation) and the colour samples."""
    if not manifest.with_role("color_sample"):
        raise EdofprojError("the pattern manifest has no colour samples (role 'color_sample')")
    return (
        [manifest.one("dots").file, manifest.one("black").file]
        + [manifest.primary(name).file for name in PRIMARY_COLORS]
        + [e.file for e in manifest.with_role("white")]
        + [e.file for e in manifest.with_role("color_sample")]
    )


def calibrate(manifest: PatternManifest, captures: Mapping[str, np.ndarray], neighbours: int = 6) -> ProCamsCalibration:
    """Geometric and colour calibration from captures ``{pattern file: (Hc, Wc, 3) image}``."""
    dots, black = manifest.one("dots"), manifest.one("black")
    if dots.dots is None or dots.grid is None:
        raise EdofprojError(f"the pattern manifest lists no dot grid for '{dots.file}'")
    names = calibration_files(manifest)
    camera_map = calibrate_geometry(
        captures[dots.file], captures[black.file], dots.dots, dots.grid, (manifest.height, manifest.width)
    )
    warped = {name: camera_map.warp(captures[name]) for name in names if name != dots.file}
    warn_if_saturated({name: warped[name] for name in names if name not in (dots.file, black.file)})
    color = calibrate_color(
        {name: warped[manifest.primary(name).file] for name in PRIMARY_COLORS},
        warped[black.file],
        [(_sample_color(e), warped[e.file]) for e in manifest.with_role("color_sample")],
        neighbours=neighbours,
    )
    return ProCamsCalibration(camera_map=camera_map, color=color, black_image=warped[black.file])


def calibrate_folders(
    pattern_dir: str | Path, capture_dir: str | Path, neighbours: int = 6
) -> tuple[PatternManifest, ProCamsCalibration]:
    """:func:`calibrate` on a pattern folder and its capture folder."""
    manifest = PatternManifest.load(pattern_dir)
    captures = read_captures(capture_dir, calibration_files(manifest))
    return manifest, calibrate(manifest, captures, neighbours)
