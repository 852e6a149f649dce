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
the colour-sample table) and ``neighbours``; with the surface captures (:mod:`.surface`) also
``surface_reflectance`` and ``surface_ambient`` (``(H, W, 3)``, projector output units).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import read_arrays, save_npz_atomic
from ..imaging.surfaces import MAX_AMBIENT
from ..limits import check_memory
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
    surface_reflectance: np.ndarray | None = field(default=None, compare=False)
    surface_ambient: np.ndarray | None = field(default=None, compare=False)
    _inverse_table: InverseTable | None = field(default=None, init=False, repr=False, compare=False)
    _rectifier: Rectifier | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def projector_hw(self) -> tuple[int, int]:
        return self.camera_map.projector_hw

    def to_output_space(self, capture: np.ndarray) -> np.ndarray:
        """A camera capture as projector output light per projector pixel, ``(H, W, 3)`` float64."""
        return self.color.camera_to_output(self.camera_map.warp(capture), self.black_image)

    def to_absolute_output(self, capture: np.ndarray) -> np.ndarray:
        """A camera capture as *absolute* projector output light, ``M^-1 c(q(x))`` (not less the
        calibration's black image): the space of the measured surface's ambient (:mod:`.surface`),
        ``(H, W, 3)`` float64. It is :meth:`to_output_space` plus ``M^-1 c_black(q(x))``."""
        return self.color.camera_to_output(self.camera_map.warp(capture), np.zeros(3))

    def check_projector_hw(self, height_width: tuple[int, ...], what: str = "the image") -> None:
        """Raise one line unless ``height_width`` is the calibrated projector's size."""
        H, W = self.projector_hw
        if tuple(height_width) != (H, W):
            raise EdofprojError(
                f"{what} is {height_width[0]}x{height_width[1]} but the calibration was made for a {H}x{W} projector "
                "(height x width)"
            )

    @property
    def has_surface(self) -> bool:
        """Whether the surface was measured (:mod:`.surface`): reflectance and ambient per pixel."""
        return self.surface_reflectance is not None and self.surface_ambient is not None

    def with_surface(self, reflectance: np.ndarray, ambient: np.ndarray) -> "ProCamsCalibration":
        """This calibration with a measured surface (``(H, W, 3)`` each, :mod:`.surface`), checked."""
        arrays = {"surface_reflectance": np.asarray(reflectance), "surface_ambient": np.asarray(ambient)}
        _check_surface_arrays(arrays, self.projector_hw, _surface_error)
        return dataclasses.replace(
            self,
            surface_reflectance=arrays["surface_reflectance"].astype(np.float32),
            surface_ambient=arrays["surface_ambient"].astype(np.float32),
        )

    def require_surface(self, what: str = "this command") -> tuple[np.ndarray, np.ndarray]:
        """The measured ``(reflectance, ambient)``, or one line saying that the calibration lacks them."""
        if self.surface_reflectance is None or self.surface_ambient is None:
            raise EdofprojError(
                f"{what} needs the surface, but the calibration was made without the surface captures "
                "(the black and white fields captured with the object in place: procams calibrate --surface-captures)"
            )
        return self.surface_reflectance, self.surface_ambient

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
            **(
                {"surface_reflectance": self.surface_reflectance, "surface_ambient": self.surface_ambient}
                if self.has_surface
                else {}
            ),
        )

    @classmethod
    def load(cls, path: str | Path) -> "ProCamsCalibration":
        """Read ``calib.npz``; every field is checked by :func:`validate_calibration_arrays` first."""
        data = read_arrays(path, what="calibration file")
        validate_calibration_arrays(data, f"calibration file '{path}'")
        camera_map = CameraMap(
            map_x=data["map_x"].astype(np.float64),
            map_y=data["map_y"].astype(np.float64),
            homography=data["homography"].astype(np.float64),
            dots_proj=data["dots_proj"].astype(np.float64),
            dots_cam=data["dots_cam"].astype(np.float64),
            camera_hw=_size_pair(data["camera_hw"]),
        )
        color = ColorCalibration(
            mixing_matrix=data["mixing_matrix"].astype(np.float64),
            black_level=data["black_level"].astype(np.float64),
            sample_inputs=data["color_inputs"].astype(np.float64),
            sample_outputs=data["color_outputs"].astype(np.float64),
            neighbours=int(data["neighbours"]),
        )
        surface = all(key in data for key in SURFACE_KEYS)
        return cls(
            camera_map=camera_map,
            color=color,
            black_image=data["black_image"].astype(np.float64),
            surface_reflectance=data["surface_reflectance"].astype(np.float32) if surface else None,
            surface_ambient=data["surface_ambient"].astype(np.float32) if surface else None,
        )


#: Largest projector or camera side a calibration file may give (pixels): beyond any display or sensor.
MAX_CALIBRATION_SIDE_PX = 32768
#: Largest condition number of a stored mixing matrix (calibration refuses 1e4; a file may not do worse).
MAX_MIXING_CONDITION = 1e4
CALIBRATION_KEYS = (
    "format",
    "projector_hw",
    "camera_hw",
    "map_x",
    "map_y",
    "homography",
    "dots_proj",
    "dots_cam",
    "mixing_matrix",
    "black_level",
    "black_image",
    "color_inputs",
    "color_outputs",
    "neighbours",
)
#: Optional keys: the measured surface (both or neither).
SURFACE_KEYS = ("surface_reflectance", "surface_ambient")


def _surface_error(message: str) -> None:
    raise EdofprojError(f"the surface measurement {message}")


def _check_surface_arrays(data: Mapping[str, np.ndarray], projector_hw: tuple[int, int], fail) -> None:
    """Both surface arrays or neither; ``(H, W, 3)``, finite, reflectance in ``[0, 1]``, ambient in
    ``[0, MAX_AMBIENT]`` (:mod:`edofproj.imaging.surfaces`)."""
    present = [key for key in SURFACE_KEYS if key in data]
    if not present:
        return
    if len(present) != len(SURFACE_KEYS):
        fail(f"has '{present[0]}' without {', '.join(k for k in SURFACE_KEYS if k not in present)}")
    H, W = projector_hw
    for key in SURFACE_KEYS:
        values = data[key]
        if values.dtype.kind not in "fiu" or values.shape != (H, W, 3):
            fail(f"has '{key}' of shape {values.shape} ({values.dtype}), not ({H}, {W}, 3) numbers")
        if not np.all(np.isfinite(values)):
            fail(f"has NaN or infinite values in '{key}'")
    if data["surface_reflectance"].min() < 0 or data["surface_reflectance"].max() > 1:
        fail("has a reflectance outside [0, 1]")
    if data["surface_ambient"].min() < 0 or data["surface_ambient"].max() > MAX_AMBIENT:
        fail(
            f"has an ambient light of {data['surface_ambient'].min():.4g}..{data['surface_ambient'].max():.4g}, "
            f"outside [0, {MAX_AMBIENT:g}] (the projector's white)"
        )


def validate_calibration_arrays(data: Mapping[str, np.ndarray], source: str) -> None:
    """Raise one line (naming ``source``) unless the arrays of a ``calib.npz`` are a calibration
    this tool could have written (the module docstring's keys):

    * sizes ``projector_hw`` ``[H, W]`` and ``camera_hw`` ``[Hc, Wc]``: two integers in
      ``1..MAX_CALIBRATION_SIDE_PX``; ``map_x``, ``map_y`` ``(H, W)`` and ``black_image`` ``(H, W, 3)``;
    * every array finite; the maps inside the camera frame, ``0 <= map_x <= Wc - 1``,
      ``0 <= map_y <= Hc - 1`` (what calibration itself requires);
    * ``homography`` 3x3; ``dots_proj`` and ``dots_cam`` ``(n, 2)`` with the same ``n``;
    * ``mixing_matrix`` 3x3 with condition number at most ``MAX_MIXING_CONDITION``;
      ``black_level`` (3,);
    * ``color_inputs`` and ``color_outputs`` ``(N, 3)``, inputs in ``[0, 1]``, and
      ``4 <= neighbours <= N`` (a 3-D local linear interpolation, as ``procams calibrate`` requires).
    """

    def fail(message: str) -> None:
        raise EdofprojError(f"{source} {message} (make a new one with 'edofproj procams calibrate')")

    if "format" not in data or data["format"].shape != () or str(data["format"]) != CALIBRATION_FORMAT:
        raise EdofprojError(f"{source} is not a calibration file (make one with 'edofproj procams calibrate')")
    missing = [key for key in CALIBRATION_KEYS if key not in data]
    if missing:
        fail(f"lacks {', '.join(missing)}")
    for key in CALIBRATION_KEYS[1:]:
        if data[key].dtype.kind not in "biuf":
            fail(f"has non-numeric '{key}' ({data[key].dtype})")
        if not np.all(np.isfinite(data[key])):
            fail(f"has NaN or infinite values in '{key}'")
    sizes = {}
    for key in ("projector_hw", "camera_hw"):
        values = data[key]
        if values.shape != (2,) or np.any(values != np.round(values)):
            fail(f"gives '{key}' {values.tolist()}, not two whole numbers [height, width]")
        if np.any(values < 1) or np.any(values > MAX_CALIBRATION_SIDE_PX):
            fail(f"gives '{key}' {values.tolist()}: each side must be 1..{MAX_CALIBRATION_SIDE_PX} pixels")
        sizes[key] = _size_pair(values)
    (H, W), (Hc, Wc) = sizes["projector_hw"], sizes["camera_hw"]
    for key, shape in (("map_x", (H, W)), ("map_y", (H, W)), ("black_image", (H, W, 3))):
        if data[key].shape != shape:
            fail(f"has '{key}' of shape {data[key].shape}, not {shape} (projector {H}x{W}, height x width)")
    for key, top in (("map_x", Wc - 1), ("map_y", Hc - 1)):
        if data[key].min() < 0 or data[key].max() > top:
            fail(
                f"has '{key}' outside the {Hc}x{Wc} (height x width) camera frame ({data[key].min():.6g}..{data[key].max():.6g})"
            )
    small: tuple[tuple[str, tuple[int, ...]], ...] = (
        ("homography", (3, 3)),
        ("mixing_matrix", (3, 3)),
        ("black_level", (3,)),
    )
    for key, wanted in small:
        if data[key].shape != wanted:
            fail(f"has '{key}' of shape {data[key].shape}, not {wanted}")
    if (
        data["dots_proj"].ndim != 2
        or data["dots_proj"].shape[1:] != (2,)
        or data["dots_cam"].shape != data["dots_proj"].shape
    ):
        fail(f"has dot lists of shapes {data['dots_proj'].shape} and {data['dots_cam'].shape}, not two (n, 2)")
    condition = np.linalg.cond(data["mixing_matrix"].astype(np.float64))
    if not condition <= MAX_MIXING_CONDITION:
        fail(f"has a singular colour-mixing matrix (condition number {condition:.3g} > {MAX_MIXING_CONDITION:g})")
    inputs, outputs = data["color_inputs"], data["color_outputs"]
    if inputs.ndim != 2 or inputs.shape[1:] != (3,) or outputs.shape != inputs.shape or len(inputs) == 0:
        fail(f"has colour tables of shapes {inputs.shape} and {outputs.shape}, not two non-empty (N, 3)")
    if inputs.min() < 0 or inputs.max() > 1:
        fail("has colour-sample inputs outside [0, 1]")
    neighbours = data["neighbours"]
    if neighbours.shape != () or neighbours != np.round(neighbours) or not 4 <= neighbours <= len(inputs):
        fail(f"gives neighbours={neighbours.tolist()}: a whole number in 4..{len(inputs)} (the colour samples)")
    _check_surface_arrays(data, (H, W), fail)


def _size_pair(values: np.ndarray) -> tuple[int, int]:
    """A stored size ``[H, W]`` as two ints."""
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


def calibration_memory_bytes(height: int, width: int, captures: int) -> int:
    """Memory of :func:`calibrate` beyond the captures: the dense map (pixel grid, homography and
    spline values, the maps: about 64 bytes per projector pixel, float64) and every capture warped
    into projector pixels, ``(H, W, 3)`` float32 (12 bytes per pixel each)."""
    return (64 + 12 * captures) * height * width


def check_calibration_memory(manifest: PatternManifest) -> None:
    """:func:`edofproj.limits.check_memory` of :func:`calibration_memory_bytes` for ``manifest``."""
    count = len(calibration_files(manifest))
    check_memory(
        calibration_memory_bytes(manifest.height, manifest.width, count),
        f"calibrating a {manifest.height}x{manifest.width} (height x width) projector from {count} captures",
        "regenerate the patterns at the projector's size (or with fewer --color-levels)",
    )


def calibrate(manifest: PatternManifest, captures: Mapping[str, np.ndarray], neighbours: int = 6) -> ProCamsCalibration:
    """Geometric and colour calibration from captures ``{pattern file: (Hc, Wc, 3) image}``."""
    dots, black = manifest.one("dots"), manifest.one("black")
    if dots.dots is None or dots.grid is None:
        raise EdofprojError(f"the pattern manifest lists no dot grid for '{dots.file}'")
    names = calibration_files(manifest)
    check_calibration_memory(manifest)
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
    check_calibration_memory(manifest)
    captures = read_captures(capture_dir, calibration_files(manifest))
    return manifest, calibrate(manifest, captures, neighbours)
