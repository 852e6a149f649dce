"""A virtual projector-camera system (ProCams): the test bed for calibration and PSF measurement.

Image formation for a projector input image ``u`` (``H x W x 3``, values in ``[0, 1]``):

1. projector response, per channel: ``o = b + (1 - b) u^gamma`` (``b``: light leaking at
   input 0, as a fraction of the full output; full output = 1);
2. optics at the screen depth (paper Eq. 9 with the haze of docs/physics.md "Energy"):
   ``s = o (*) p + (1 - sum p) mean(o)``, exactly :func:`edofproj.imaging.project` (or
   :func:`~edofproj.imaging.render_depth_map` for a screen with a depth map) inside the image,
   on a canvas with a black margin of ``K//2 + 1`` px that also keeps the direct light spilling
   past the image border (the haze stays spread over the image);
3. the surface (optional, :mod:`edofproj.imaging.surfaces`): a reflectance ``rho(x)`` per
   projector pixel and primary, in ``[0, 1]`` (None: a white screen, ``rho = 1``), and an ambient
   illuminance ``E`` (projector-output units, reflected like the projection):
   ``s <- rho ⊙ (s + E)``; the canvas's margin takes the reflectance of the nearest image pixel;
4. camera colour: ``c = M s + a`` (``M``: 3x3 colour-mixing matrix, ``a``: ambient light);
5. camera geometry: camera pixel ``q = (u, v)`` sees projector coordinate ``x = H^-1(w)``, with
   the pinhole position ``w = c0 + (q - c0)(1 + k1 |q - c0|^2 / f^2)`` (radial lens
   distortion, ``c0`` the image centre, ``f`` half the larger camera side) and ``H`` a
   homography (projector -> pinhole camera coordinates). Each camera pixel integrates the
   piecewise-constant projector pixels over its footprint (``s x s`` supersampling);
6. sensor: additive Gaussian noise ``N(0, sigma^2)``, clipped to ``[0, 1]``, quantized to 8 bits.

The camera is linear (a RAW capture); a real camera's tone curve must be undone first.

What calibration can recover is relative to the black field and normalized by the full
primaries (paper Sec. 5.2: "let the outputs of the three single-color images be (1,0,0),
(0,1,0), (0,0,1)"): the normalized response ``(o(u) - o(0)) / (o(1) - o(0)) = u^gamma`` and the
effective mixing matrix ``M (1 - b)`` (:attr:`VirtualProCams.effective_mixing_matrix`).
On a textured surface, seen through that calibration (``M_eff^-1 c``, with the colour calibration
made on a white screen) a pixel away from image borders and depth edges shows, in closed form,

    M_eff^-1 c = rho ⊙ (PSF ⊛ u^gamma) + a,    a = rho ⊙ (b + E) / (1 - b) + M_eff^-1 a_cam

(:meth:`VirtualProCams.true_surface`): the model of :mod:`edofproj.imaging.surfaces` with
``s = rho``, which :mod:`edofproj.procams.surface` measures.
Coordinates are ``(x, y)`` = (column, row), pixel centres at integers (OpenCV).
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import save_npz_atomic
from ..imaging import haze_term, layer_weights, project, render_depth_map
from ..imaging.surfaces import check_illuminance, check_reflectance
from ..optics.psf_bank import PSFBank
from .calibration import ProCamsCalibration
from .capture_io import CAPTURE_INFO_JSON, atomic_folder, write_rgb_png
from .color import RESPONSE_LUT_SIZE, ColorCalibration
from .geometry import CameraMap
from .patterns import MANIFEST_NAME, PatternManifest, read_pattern

DEFAULT_MIXING_MATRIX = np.array([[0.62, 0.12, 0.04], [0.10, 0.60, 0.10], [0.03, 0.12, 0.58]])
"""Camera RGB per unit projector output: column j is the camera's response to primary j."""

GROUND_TRUTH_JSON = "ground_truth.json"
GROUND_TRUTH_NPZ = "ground_truth.npz"
TRUE_PSF_NPZ = "true_psf.npz"


def _rgb_triple(value) -> tuple[float, float, float]:
    """One value per RGB channel (a scalar is used for all three)."""
    red, green, blue = (float(v) for v in np.broadcast_to(value, (3,)))
    return red, green, blue


@dataclass
class VirtualProCams:
    """Ground truth of a simulated projector-camera system (module docstring for the model).

    ``psf``: ``(n, 3, K, K)`` PSFs in projector pixels (``n = 1`` for a flat screen, or one per
    ``layer_depths_m`` with a ``depth_map_m (H, W)``). ``homography``: 3x3, projector ``(x, y, 1)``
    -> pinhole camera coordinates. ``depth_m`` / ``pixel_pitch_m``: the flat screen's depth
    and projector pixel pitch there (recorded, not used by the simulation).
    """

    projector_hw: tuple[int, int]
    camera_hw: tuple[int, int]
    psf: np.ndarray
    homography: np.ndarray
    radial_k1: float = 0.0
    gamma: tuple[float, float, float] = (2.2, 2.2, 2.2)
    projector_black: float = 0.01
    mixing_matrix: np.ndarray = field(default_factory=lambda: DEFAULT_MIXING_MATRIX.copy())
    ambient: tuple[float, float, float] = (0.02, 0.02, 0.02)
    noise_sigma: float = 0.005
    supersampling: int = 3
    depth_m: float | None = None
    pixel_pitch_m: float | None = None
    depth_map_m: np.ndarray | None = None
    layer_depths_m: np.ndarray | None = None
    reflectance: np.ndarray | None = None
    surface_ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self.psf = np.asarray(self.psf, dtype=np.float64)
        if self.psf.ndim == 3:
            self.psf = self.psf[None]
        if self.psf.ndim != 4 or self.psf.shape[1] != 3 or self.psf.shape[-1] % 2 == 0:
            raise EdofprojError(f"the virtual ProCams needs RGB PSFs (n, 3, K, K) with K odd, got {self.psf.shape}")
        if (self.depth_map_m is None) != (self.layer_depths_m is None):
            raise EdofprojError("a depth map needs layer_depths_m (one PSF per layer), and vice versa")
        if self.depth_map_m is None and self.psf.shape[0] != 1:
            raise EdofprojError(f"a flat screen takes one PSF, got {self.psf.shape[0]}")
        self.homography = np.asarray(self.homography, dtype=np.float64)
        self.mixing_matrix = np.asarray(self.mixing_matrix, dtype=np.float64)
        self.gamma = _rgb_triple(self.gamma)
        self.ambient = _rgb_triple(self.ambient)
        if not (0.0 <= self.projector_black < 1.0):
            raise EdofprojError(f"projector_black={self.projector_black} must be in [0, 1)")
        self.surface_ambient = _rgb_triple(self.surface_ambient)
        for value in self.surface_ambient:
            check_illuminance(value, "surface_ambient")
        if self.reflectance is not None:
            rho = check_reflectance(
                self.reflectance,
                (int(self.projector_hw[0]), int(self.projector_hw[1])),
                "the virtual surface's reflectance",
            )
            self.reflectance = rho[0].permute(1, 2, 0).numpy().astype(np.float64)

    # ------------------------------------------------------------------ a plausible rig
    @classmethod
    def example(
        cls,
        projector_hw: tuple[int, int],
        psf,
        seed: int = 0,
        camera_scale: float = 3.0,
        fill: float = 0.75,
        rotation_deg: float = 4.0,
        perspective: float = 0.04,
        radial_k1: float = 0.02,
        **params,
    ) -> "VirtualProCams":
        """A rig whose camera sees the projector image at ``camera_scale`` camera pixels per
        projector pixel, filling ``fill`` of the camera frame, turned by up to ``rotation_deg``,
        with perspective (corners moved by up to ``perspective`` of the image size) and barrel
        distortion ``radial_k1``; random but fixed by ``seed``. ``params``: other fields."""
        H, W = projector_hw
        rng = np.random.default_rng(seed)
        camera_hw = (int(math.ceil(H * camera_scale / fill)), int(math.ceil(W * camera_scale / fill)))
        corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
        centre_proj = np.array([(W - 1) / 2, (H - 1) / 2])
        centre_cam = np.array([(camera_hw[1] - 1) / 2, (camera_hw[0] - 1) / 2])
        angle = math.radians(rng.uniform(-rotation_deg, rotation_deg))
        rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        jitter = rng.uniform(-1, 1, (4, 2)) * perspective * camera_scale * min(H, W)
        target = centre_cam + (corners - centre_proj) @ rotation.T * camera_scale + jitter
        homography = cv2.getPerspectiveTransform(corners.astype(np.float32), target.astype(np.float32))
        rig = cls(
            projector_hw=(H, W), camera_hw=camera_hw, psf=psf, homography=homography, radial_k1=radial_k1, **params
        )
        u, v = rig.projector_points_to_camera(corners[:, 0], corners[:, 1])
        if u.min() < 0 or v.min() < 0 or u.max() > camera_hw[1] - 1 or v.max() > camera_hw[0] - 1:
            raise EdofprojError("the example camera does not see the whole projector image; lower fill")
        return rig

    @classmethod
    def from_capture_folder(cls, folder: str | Path) -> "VirtualProCams":
        """The rig that wrote the capture folder ``folder`` (:func:`simulate_captures`), rebuilt
        from its ``ground_truth.json`` and ``ground_truth.npz`` (flat screens)."""
        folder = Path(folder)
        try:
            info = json.loads((folder / GROUND_TRUTH_JSON).read_text(encoding="utf-8"))
            with np.load(folder / GROUND_TRUTH_NPZ, allow_pickle=False) as data:
                psf = data["psf"].astype(np.float64)
                reflectance = data["reflectance"].astype(np.float64) if "reflectance" in data else None
            depth_mm = info.get("depth_mm")
            return cls(
                projector_hw=(int(info["projector_hw"][0]), int(info["projector_hw"][1])),
                camera_hw=(int(info["camera_hw"][0]), int(info["camera_hw"][1])),
                psf=psf,
                homography=np.asarray(info["homography"]),
                radial_k1=float(info["radial_k1"]),
                gamma=_rgb_triple(info["gamma"]),
                projector_black=float(info["projector_black"]),
                mixing_matrix=np.asarray(info["mixing_matrix"]),
                ambient=_rgb_triple(info["ambient"]),
                noise_sigma=float(info["noise_sigma"]),
                supersampling=int(info["supersampling"]),
                depth_m=None if depth_mm is None else float(depth_mm) * 1e-3,
                pixel_pitch_m=info.get("pixel_pitch_m"),
                reflectance=reflectance,
                surface_ambient=_rgb_triple(info.get("surface_ambient", 0.0)),
            )
        except FileNotFoundError as exc:
            raise EdofprojError(
                f"'{folder}' is not a folder written by 'edofproj procams simulate' (no {Path(str(exc.filename)).name})"
            ) from None
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            raise EdofprojError(f"cannot rebuild the virtual ProCams from '{folder}': {exc}") from None

    # ------------------------------------------------------------------ radiometry
    def projector_output(self, image: np.ndarray) -> np.ndarray:
        """Linear light per channel: ``b + (1 - b) u^gamma`` for input ``u`` in ``[0, 1]``."""
        u = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
        b = self.projector_black
        return b + (1.0 - b) * u ** np.asarray(self.gamma)

    def normalized_response(self, image: np.ndarray) -> np.ndarray:
        """``(o(u) - o(0)) / (o(1) - o(0)) = u^gamma``: the response that colour calibration recovers."""
        return np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0) ** np.asarray(self.gamma)

    @property
    def effective_mixing_matrix(self) -> np.ndarray:
        """Camera response (above black) to the full primaries: ``M (o(1) - o(0)) = M (1 - b)``."""
        return self.mixing_matrix * (1.0 - self.projector_black)

    @property
    def black_capture_level(self) -> np.ndarray:
        """Noise-free camera value of the black field away from the border: ``M b 1 + a``."""
        return self.mixing_matrix @ np.full(3, self.projector_black) + np.asarray(self.ambient)

    @property
    def canvas_margin_px(self) -> int:
        return self.psf.shape[-1] // 2 + 1

    def screen_image(self, image: np.ndarray) -> np.ndarray:
        """The light on the screen, ``(H + 2m, W + 2m, 3)`` in projector pixels, ``m`` = :attr:`canvas_margin_px`.

        Inside the image this is exactly :func:`edofproj.imaging.project` (or
        :func:`~edofproj.imaging.render_depth_map`) of the projector output: the direct light
        (convolution) plus the haze ``(1 - sum p) mean(o)`` spread uniformly over the image.
        The canvas's margin receives the direct light spilling past the image border only.
        """
        H, W = self.projector_hw
        if image.shape[:2] != (H, W):
            raise EdofprojError(f"pattern is {image.shape[0]}x{image.shape[1]}, the projector {H}x{W} (height x width)")
        m = self.canvas_margin_px
        output = torch.from_numpy(np.ascontiguousarray(self.projector_output(image).transpose(2, 0, 1)))[None]
        canvas = torch.nn.functional.pad(output, (m, m, m, m))
        psf = torch.from_numpy(self.psf)
        with torch.no_grad():
            if self.depth_map_m is None:
                direct = project(canvas, psf, haze=False)
                haze = haze_term(output, psf)
            else:
                if self.layer_depths_m is None:
                    raise EdofprojError("a depth map needs layer_depths_m (one PSF per layer)")
                depth = np.pad(np.asarray(self.depth_map_m, dtype=np.float64), m, mode="edge")
                direct = render_depth_map(canvas, depth, psf, layers=list(self.layer_depths_m), haze=False)
                weights = layer_weights(self.depth_map_m, self.layer_depths_m).to(output.dtype)  # (n, H, W)
                haze = haze_term(output * weights[0], psf[0:1])
                for layer in range(1, len(self.layer_depths_m)):
                    haze = haze + haze_term(output * weights[layer], psf[layer : layer + 1])
        screen = direct[0].numpy()
        screen[:, m : m + H, m : m + W] += haze[0].numpy()
        screen = screen.transpose(1, 2, 0)
        if self.reflectance is not None or max(self.surface_ambient) > 0:
            rho = np.ones((H, W, 3)) if self.reflectance is None else self.reflectance
            screen = np.pad(rho, ((m, m), (m, m), (0, 0)), mode="edge") * (screen + np.asarray(self.surface_ambient))
        return screen

    def true_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The surface as a white-screen calibration sees it (module docstring), ``(H, W, 3)`` each:
        reflectance ``rho`` and ambient ``a = rho (b + E) / (1 - b) + M_eff^-1 a_cam``, in closed form."""
        H, W = self.projector_hw
        rho = np.ones((H, W, 3)) if self.reflectance is None else self.reflectance
        b = self.projector_black
        camera_ambient = np.linalg.solve(self.effective_mixing_matrix, np.asarray(self.ambient))
        ambient = rho * (b + np.asarray(self.surface_ambient)) / (1.0 - b) + camera_ambient
        return rho.copy(), ambient

    # ------------------------------------------------------------------ geometry
    @property
    def _distortion_centre_and_scale(self) -> tuple[np.ndarray, float]:
        Hc, Wc = self.camera_hw
        return np.array([(Wc - 1) / 2, (Hc - 1) / 2]), max(Hc, Wc) / 2

    def camera_points_to_projector(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Projector ``(x, y)`` seen by camera points ``(u, v)`` (module docstring, step 4)."""
        centre, scale = self._distortion_centre_and_scale
        du, dv = np.asarray(u, float) - centre[0], np.asarray(v, float) - centre[1]
        factor = 1.0 + self.radial_k1 * (du**2 + dv**2) / scale**2
        w = np.stack([centre[0] + du * factor, centre[1] + dv * factor, np.ones_like(du)])
        x = np.tensordot(np.linalg.inv(self.homography), w, axes=1)
        return x[0] / x[2], x[1] / x[2]

    def projector_points_to_camera(self, x, y, iterations: int = 50) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``(u, v)`` of projector points ``(x, y)``: the inverse of
        :meth:`camera_points_to_projector` (the distortion inverted by fixed-point iteration)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        w = np.tensordot(self.homography, np.stack([x, y, np.ones_like(x)]), axes=1)
        centre, scale = self._distortion_centre_and_scale
        dw = np.stack([w[0] / w[2] - centre[0], w[1] / w[2] - centre[1]])
        d = dw.copy()
        for _ in range(iterations):
            d = dw / (1.0 + self.radial_k1 * (d[0] ** 2 + d[1] ** 2) / scale**2)
        return centre[0] + d[0], centre[1] + d[1]

    def true_camera_map(self) -> tuple[np.ndarray, np.ndarray]:
        """For every projector pixel ``(H, W)``, the camera ``(u, v)`` that sees its centre."""
        H, W = self.projector_hw
        y, x = np.mgrid[0:H, 0:W].astype(np.float64)
        return self.projector_points_to_camera(x, y)

    @functools.cached_property
    def _camera_sample_map(self) -> np.ndarray:
        """Integer canvas coordinates ``(col, row)`` of the ``s x s`` sub-samples of every camera
        pixel, ``(Hc s, Wc s, 2)`` int16, for ``cv2.remap`` with nearest-pixel lookup."""
        Hc, Wc = self.camera_hw
        s = self.supersampling
        offsets = (np.arange(s) + 0.5) / s - 0.5
        v = (np.arange(Hc)[:, None] + offsets[None, :]).ravel()
        u = (np.arange(Wc)[:, None] + offsets[None, :]).ravel()
        uu, vv = np.meshgrid(u, v)
        x, y = self.camera_points_to_projector(uu, vv)
        m = self.canvas_margin_px
        col = np.clip(np.floor(x + m + 0.5), -1, 32000)
        row = np.clip(np.floor(y + m + 0.5), -1, 32000)
        return np.stack([col, row], axis=-1).astype(np.int16)

    def camera_pixels_per_projector_pixel(self) -> float:
        """Smallest linear magnification (camera px per projector px) over the projector image."""
        map_u, map_v = self.true_camera_map()
        du_dx, dv_dx = np.gradient(map_u, axis=1), np.gradient(map_v, axis=1)
        du_dy, dv_dy = np.gradient(map_u, axis=0), np.gradient(map_v, axis=0)
        return float(np.sqrt(np.abs(du_dx * dv_dy - du_dy * dv_dx)).min())

    # ------------------------------------------------------------------ capture
    def capture(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The camera's 8-bit capture of projector input ``image`` as ``(Hc, Wc, 3)`` float32 in
        ``[0, 1]``: :meth:`capture_counts` ``/ 255``."""
        return self.capture_counts(image, rng).astype(np.float32) / np.float32(255.0)

    def capture_counts(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The sensor's 8-bit counts of projector input ``image``, ``(Hc, Wc, 3)`` uint8 (module
        docstring, steps 2-5): ``round(255 clip(c + noise, 0, 1))``."""
        screen = self.screen_image(image)
        camera_light = (screen @ self.mixing_matrix.T).astype(np.float32)  # (H + 2m, W + 2m, 3)
        # map2=None (map1 holds both coordinates) is valid OpenCV but missing from its stubs
        samples = cv2.remap(
            camera_light,
            self._camera_sample_map,
            None,
            cv2.INTER_NEAREST,  # type: ignore[call-overload]
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )  # black beyond the canvas
        Hc, Wc = self.camera_hw
        pixels = cv2.resize(samples, (Wc, Hc), interpolation=cv2.INTER_AREA)  # area mean of the sub-samples
        pixels += np.asarray(self.ambient, dtype=np.float32)
        pixels += np.float32(self.noise_sigma) * rng.standard_normal(pixels.shape, dtype=np.float32)
        np.clip(pixels, 0.0, 1.0, out=pixels)
        pixels *= np.float32(255.0)
        return np.rint(pixels, out=pixels).astype(np.uint8)

    # ------------------------------------------------------------------ ground truth
    def ideal_calibration(self, levels: int = 6, response_lut_size: int | None = None):
        """The calibration a perfect measurement of this rig gives (no captures, no noise): the true
        camera map, the effective mixing matrix, the black capture level ``M b 1 + a`` everywhere
        and the normalized response ``u^gamma`` sampled on ``levels^3`` colours. For tests and
        benchmarks of what comes after calibration."""
        H, W = self.projector_hw
        map_x, map_y = self.true_camera_map()
        camera_map = CameraMap(
            map_x=map_x,
            map_y=map_y,
            homography=self.homography,
            dots_proj=np.zeros((0, 2)),
            dots_cam=np.zeros((0, 2)),
            camera_hw=self.camera_hw,
        )
        values = np.linspace(0.0, 1.0, levels)
        inputs = np.stack(np.meshgrid(values, values, values, indexing="ij"), axis=-1).reshape(-1, 3)
        color = ColorCalibration(
            mixing_matrix=self.effective_mixing_matrix,
            black_level=self.black_capture_level,
            sample_inputs=inputs,
            sample_outputs=self.normalized_response(inputs),
        )
        return ProCamsCalibration(
            camera_map=camera_map,
            color=color,
            black_image=np.broadcast_to(self.black_capture_level, (H, W, 3)).copy(),
            response_lut_size=RESPONSE_LUT_SIZE if response_lut_size is None else response_lut_size,
        )

    def ground_truth_json(self) -> dict:
        return {
            "projector_hw": list(self.projector_hw),
            "camera_hw": list(self.camera_hw),
            "depth_mm": None if self.depth_m is None else self.depth_m * 1e3,
            "pixel_pitch_m": self.pixel_pitch_m,
            "gamma": list(self.gamma),
            "projector_black": self.projector_black,
            "mixing_matrix": self.mixing_matrix.tolist(),
            "effective_mixing_matrix": self.effective_mixing_matrix.tolist(),
            "ambient": list(self.ambient),
            "surface_ambient": list(self.surface_ambient),
            "textured_surface": self.reflectance is not None,
            "black_capture_level": self.black_capture_level.tolist(),
            "homography": self.homography.tolist(),
            "radial_k1": self.radial_k1,
            "noise_sigma": self.noise_sigma,
            "supersampling": self.supersampling,
            "camera_pixels_per_projector_pixel": self.camera_pixels_per_projector_pixel(),
            "psf_window": int(self.psf.shape[-1]),
            "energy_in_window": self.psf.sum(axis=(-1, -2)).tolist(),
        }


def _surface_truth(rig: VirtualProCams) -> dict[str, np.ndarray]:
    """``reflectance`` and ``true_surface_ambient`` (:meth:`VirtualProCams.true_surface`) of a textured rig."""
    if rig.reflectance is None:
        return {}
    rho, ambient = rig.true_surface()
    return {"reflectance": rho.astype(np.float32), "true_surface_ambient": ambient.astype(np.float32)}


def simulate_captures(
    rig: VirtualProCams, pattern_dir: str | Path, out_dir: str | Path, seed: int = 0, overwrite: bool = False, log=None
) -> PatternManifest:
    """Capture every pattern of ``pattern_dir`` with ``rig`` into ``out_dir`` (written atomically).

    Writes one PNG per pattern under the pattern's name, ``ground_truth.json`` (the rig's
    parameters), ``ground_truth.npz`` (``psf``, ``camera_map_x/y`` = the true camera coordinates
    of every projector pixel, ``homography``, ``mixing_matrix``, ``effective_mixing_matrix``),
    ``true_psf.npz`` (the PSF in the ``edofproj psf`` format, flat screens only) and
    ``captures.json`` (``{"depth_mm": ...}``, the screen distance, as a lab log would).
    """
    manifest = PatternManifest.load(pattern_dir)
    if (manifest.height, manifest.width) != tuple(rig.projector_hw):
        raise EdofprojError(
            f"patterns are {manifest.height}x{manifest.width} but the virtual projector is "
            f"{rig.projector_hw[0]}x{rig.projector_hw[1]} (height x width)"
        )
    rng = np.random.default_rng(seed)
    map_x, map_y = rig.true_camera_map()
    with atomic_folder(out_dir, overwrite=overwrite, what="edofproj procams simulate") as tmp:
        for number, entry in enumerate(manifest.entries):
            pattern = read_pattern(pattern_dir, entry, manifest)
            write_rgb_png(tmp / entry.file, rig.capture(pattern, rng))
            if log is not None and (number + 1) % 50 == 0:
                log(f"  {number + 1}/{len(manifest.entries)} captures")
        (tmp / GROUND_TRUTH_JSON).write_text(json.dumps(rig.ground_truth_json(), indent=1) + "\n", encoding="utf-8")
        save_npz_atomic(
            tmp / GROUND_TRUTH_NPZ,
            psf=rig.psf.astype(np.float32),
            camera_map_x=map_x,
            camera_map_y=map_y,
            homography=rig.homography,
            mixing_matrix=rig.mixing_matrix,
            effective_mixing_matrix=rig.effective_mixing_matrix,
            gamma=np.asarray(rig.gamma),
            **_surface_truth(rig),
        )
        if rig.depth_m is not None and rig.depth_map_m is None:
            PSFBank(
                psf=torch.from_numpy(rig.psf),
                depths_m=np.array([rig.depth_m]),
                pixel_pitch_m=np.array([rig.pixel_pitch_m if rig.pixel_pitch_m is not None else np.nan]),
                description="ground truth of the virtual ProCams",
            ).save(tmp / TRUE_PSF_NPZ)
        info = {
            "depth_mm": None if rig.depth_m is None else rig.depth_m * 1e3,
            "patterns": str(Path(pattern_dir).resolve() / MANIFEST_NAME),
            "source": "edofproj procams simulate",
        }
        (tmp / CAPTURE_INFO_JSON).write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    return manifest
