"""The PSF bank: RGB PSFs of a DOE across screen depths, in projector pixels.

``PSF_c(z) = sum_k w_ck PSF_lambda_k(z)`` (SPD-weighted, see :mod:`.spectra`), each pixel
holding its share of the energy through the pupil. ``energy_in_window`` is the sum over
the window; the rest, ``haze_fraction = 1 - energy_in_window``, is light thrown outside the
window, rendered as a uniform haze by :mod:`edofproj.imaging`.

File contract (``edofproj psf``): ``psf`` float32 (n_depths, C, K, K), ``depths_m``,
``pixel_pitch_m`` (screen pitch q(z)), ``energy_in_window`` (n_depths, C), plus
``wavelengths_m`` and ``channel_weights`` (C, n_lambda).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import read_arrays, save_npz_atomic
from .aberrations import PupilAberration, aberration_from_config
from .fourier_engine import FourierPSFEngine
from .geometry import ProjectorGeometry
from .lens_prescription import lens_pupil_from_config
from .psf_checks import validate_psf
from .radial_engine import RadialPSFEngine, check_depths, check_window
from .spectra import Spectrum, check_spectral_sampling, pupil_path_difference_m


@dataclass
class PSFBank:
    """PSFs for a set of depths. ``psf``: torch tensor (n_depths, C, K, K)."""

    psf: torch.Tensor
    depths_m: np.ndarray
    pixel_pitch_m: np.ndarray
    wavelengths_m: np.ndarray | None = None
    channel_weights: np.ndarray | None = None
    description: str = ""

    @property
    def window(self) -> int:
        return int(self.psf.shape[-1])

    @property
    def energy_in_window(self) -> torch.Tensor:
        """(n_depths, C): fraction of the pupil energy that lands inside the window."""
        return self.psf.sum(dim=(-1, -2))

    @property
    def haze_fraction(self) -> torch.Tensor:
        """(n_depths, C): fraction of the pupil energy outside the window (rendered as haze)."""
        return 1.0 - self.energy_in_window

    def save(self, path: str | Path) -> None:
        psf = self.psf.detach().cpu().numpy()
        if not np.all(np.isfinite(psf)):
            raise EdofprojError("refusing to write a PSF with NaN or infinite values")
        extra = {}
        if self.wavelengths_m is not None:
            extra["wavelengths_m"] = np.asarray(self.wavelengths_m, dtype=np.float64)
        if self.channel_weights is not None:
            extra["channel_weights"] = np.asarray(self.channel_weights, dtype=np.float64)
        save_npz_atomic(
            path,
            psf=psf.astype(np.float32),
            depths_m=np.asarray(self.depths_m, dtype=np.float64),
            pixel_pitch_m=np.asarray(self.pixel_pitch_m, dtype=np.float64),
            energy_in_window=self.energy_in_window.detach().cpu().numpy().astype(np.float64),
            description=np.array(self.description),
            **extra,
        )

    @classmethod
    def load(cls, path: str | Path) -> "PSFBank":
        data = read_arrays(path, "PSF file")
        missing = [key for key in ("psf", "depths_m", "pixel_pitch_m") if key not in data]
        if missing:
            raise EdofprojError(
                f"PSF file '{path}' lacks {', '.join(missing)}: write PSF files with 'edofproj psf' "
                "or 'edofproj procams estimate-psf'"
            )
        psf, depths, pitch = data["psf"], data["depths_m"], data["pixel_pitch_m"]
        if psf.dtype.kind not in "fiu" or depths.dtype.kind not in "fiu":
            raise EdofprojError(f"PSF file '{path}': psf and depths_m must be numbers")
        validate_psf(
            psf,
            depths,
            source=f"PSF file '{path}'",
            measured=True,
            fix="write it with 'edofproj psf' or 'edofproj procams estimate-psf'",
        )
        return cls(
            psf=torch.from_numpy(psf.astype(np.float32)),
            depths_m=np.asarray(depths, dtype=float),
            pixel_pitch_m=np.asarray(pitch, dtype=float),
            wavelengths_m=data["wavelengths_m"] if "wavelengths_m" in data else None,
            channel_weights=data["channel_weights"] if "channel_weights" in data else None,
            description=str(data["description"]) if "description" in data else "",
        )


class PSFSimulator:
    """Differentiable RGB PSFs of a DOE: builds an engine once, then ``sim(doe, depths_m)``.

    ``engine``: ``"radial"`` (radially symmetric DOEs; fast) or ``"2d"`` (any height map).
    """

    def __init__(
        self,
        geometry: ProjectorGeometry,
        spectrum: Spectrum,
        window: int,
        pupil_samples: int = 1024,
        engine: str = "radial",
        dtype: torch.dtype = torch.float64,
        device=None,
        aberration: PupilAberration | None = None,
    ):
        self.geometry = geometry
        self.spectrum = spectrum
        self.window = check_window(window)
        self.engine_name = engine
        self.dtype = dtype
        self.engine: RadialPSFEngine | FourierPSFEngine
        if engine == "radial":
            self.engine = RadialPSFEngine(
                geometry, spectrum.wavelengths_m, window, pupil_samples, dtype, device, aberration=aberration
            )
        elif engine == "2d":
            self.engine = FourierPSFEngine(
                geometry, spectrum.wavelengths_m, window, pupil_samples, dtype, device, aberration=aberration
            )
        else:
            raise EdofprojError(f"unknown engine '{engine}' (known: radial, 2d)")
        self.channel_weights = torch.as_tensor(spectrum.weights, dtype=dtype, device=device)

    def __call__(self, doe, depths_m) -> torch.Tensor:
        """RGB PSFs (n_depths, C, K, K) of ``doe`` (None: the bare lens) at ``depths_m``."""
        if doe is not None and not doe.radially_symmetric and self.engine_name == "radial":
            raise EdofprojError(f"the '{doe.name}' DOE is not radially symmetric: use --engine 2d")
        mono = self.engine.psf(doe, depths_m)  # (Z, L, K, K)
        psf = torch.einsum("cl,zlij->zcij", self.channel_weights.to(mono.dtype), mono)
        if not torch.all(torch.isfinite(psf)):
            raise EdofprojError("the simulated PSF contains NaN or infinite values")
        return psf

    def bank(self, doe, depths_m, description: str = "") -> PSFBank:
        depths_m = check_depths(depths_m)
        with torch.no_grad():
            psf = self(doe, depths_m)
        validate_psf(
            psf,
            depths_m,
            source=f"the simulated PSF of {doe.describe() if doe is not None else 'the lens'}",
            measured=False,
            fix="check psf.window and psf.pupil_samples",
        )
        return PSFBank(
            psf=psf,
            depths_m=depths_m,
            pixel_pitch_m=self.geometry.pixel_pitch_m(depths_m),
            wavelengths_m=self.spectrum.wavelengths_m,
            channel_weights=self.spectrum.weights,
            description=description or (doe.describe() if doe is not None else "lens"),
        )


def design_engine(doe, configured: str = "radial") -> str:
    """The propagation engine that simulates ``doe``: the configured one (``psf.engine``) for the
    bare lens (``None``) and radially symmetric designs, the 2-D engine for any other design
    (the radial engine cannot represent it)."""
    if doe is None or doe.radially_symmetric:
        return configured
    return "2d"


def simulator_from_config(
    cfg, wavelength_nm: float | None = None, engine: str | None = None, window: int | None = None, device=None
) -> PSFSimulator:
    """A :class:`PSFSimulator` for a :class:`~edofproj.config.Config`."""
    geometry = ProjectorGeometry.from_config(cfg.optics)
    if wavelength_nm is not None:
        spectrum = Spectrum.monochromatic(wavelength_nm)
    else:
        spectrum = Spectrum.from_config(cfg.spectrum)
        check_spectral_sampling(cfg.spectrum, spectrum, pupil_path_difference_m(geometry, cfg))
    dtype = torch.float64 if cfg.psf.precision == "float64" else torch.float32
    return PSFSimulator(
        geometry,
        spectrum,
        window or cfg.psf.window,
        cfg.psf.pupil_samples,
        engine or cfg.psf.engine,
        dtype,
        device,
        aberration=lens_pupil_from_config(cfg.optics, spectrum.wavelengths_m, cfg.psf.pupil_samples)
        or aberration_from_config(cfg.optics),
    )
