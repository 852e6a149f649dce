"""Wavelength sampling and the RGB primaries' spectral power distributions (SPDs).

Each RGB channel's PSF is the SPD-weighted sum of monochromatic PSFs,

    PSF_c = sum_k w_ck PSF_lambda_k,   w_ck = SPD_c(lambda_k) / sum_k SPD_c(lambda_k),

over wavelengths sampled from 400 to 700 nm (paper: 30 nm steps, 11 samples).

The default SPDs are an assumption (the paper's measured ones are not published): three
LED-like Gaussian peaks. Measured SPDs are read from a CSV ``wavelength_nm,r,g,b``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import EdofprojError

WAVELENGTH_RANGE_NM = (350.0, 1000.0)


def check_wavelengths_nm(wavelengths_nm) -> np.ndarray:
    """Validate wavelengths (nm) against the supported 350-1000 nm range."""
    lam = np.atleast_1d(np.asarray(wavelengths_nm, dtype=float))
    lo, hi = WAVELENGTH_RANGE_NM
    bad = lam[~np.isfinite(lam) | (lam < lo) | (lam > hi)]
    if bad.size:
        raise EdofprojError(f"wavelength {bad[0]:g} nm is outside the allowed {lo:g}-{hi:g} nm")
    return lam


def sample_wavelengths_nm(lo_nm: float, hi_nm: float, step_nm: float) -> np.ndarray:
    """Samples lo, lo+step, ... <= hi (inclusive within rounding)."""
    n = int(np.floor((hi_nm - lo_nm) / step_nm + 1e-9)) + 1
    return check_wavelengths_nm(lo_nm + step_nm * np.arange(n))


@dataclass(frozen=True)
class Spectrum:
    """Wavelength samples and per-channel weights.

    ``wavelengths_m``: (n_lambda,). ``weights``: (n_channels, n_lambda), rows sum to 1.
    """

    wavelengths_m: np.ndarray
    weights: np.ndarray

    @property
    def n_channels(self) -> int:
        return int(self.weights.shape[0])

    @classmethod
    def monochromatic(cls, wavelength_nm: float) -> "Spectrum":
        lam = check_wavelengths_nm([wavelength_nm])
        return cls(wavelengths_m=lam * 1e-9, weights=np.ones((1, 1)))

    @classmethod
    def led(cls, wavelengths_nm, peaks_nm=(620.0, 530.0, 460.0), fwhm_nm=(20.0, 35.0, 25.0)) -> "Spectrum":
        """Gaussian LED-like primaries (an assumption, documented as such)."""
        lam = check_wavelengths_nm(wavelengths_nm)
        sigma = np.asarray(fwhm_nm, dtype=float)[:, None] / (2 * np.sqrt(2 * np.log(2)))
        spd = np.exp(-0.5 * ((lam[None, :] - np.asarray(peaks_nm, float)[:, None]) / sigma) ** 2)
        return cls._from_spd(lam, spd, "LED model")

    @classmethod
    def from_csv(cls, path: str | Path, wavelengths_nm) -> "Spectrum":
        """Measured SPDs from a CSV with columns ``wavelength_nm,r,g,b`` (header optional)."""
        lam = check_wavelengths_nm(wavelengths_nm)
        try:
            table = np.genfromtxt(path, delimiter=",", comments="#", dtype=float)
        except (OSError, ValueError) as exc:
            raise EdofprojError(f"cannot read SPD file '{path}': {exc}") from None
        table = np.atleast_2d(table)
        table = table[np.all(np.isfinite(table), axis=1)] if table.size else table
        if table.ndim != 2 or table.shape[1] != 4 or table.shape[0] < 2:
            raise EdofprojError(f"SPD file '{path}' must have rows 'wavelength_nm,r,g,b' (at least two rows)")
        order = np.argsort(table[:, 0])
        table = table[order]
        if np.any(table[:, 1:] < 0):
            raise EdofprojError(f"SPD file '{path}' has negative power values")
        spd = np.stack([np.interp(lam, table[:, 0], table[:, c], left=0.0, right=0.0) for c in (1, 2, 3)])
        return cls._from_spd(lam, spd, f"SPD file '{path}'")

    @classmethod
    def _from_spd(cls, lam_nm: np.ndarray, spd: np.ndarray, what: str) -> "Spectrum":
        total = spd.sum(axis=1, keepdims=True)
        if np.any(total <= 0):
            raise EdofprojError(f"{what}: a primary has no power at the sampled wavelengths")
        return cls(wavelengths_m=lam_nm * 1e-9, weights=spd / total)

    @classmethod
    def from_config(cls, spectrum_cfg) -> "Spectrum":
        lam = sample_wavelengths_nm(
            spectrum_cfg.wavelength_min_nm, spectrum_cfg.wavelength_max_nm, spectrum_cfg.wavelength_step_nm
        )
        if spectrum_cfg.spd_csv:
            return cls.from_csv(spectrum_cfg.spd_csv, lam)
        return cls.led(lam, spectrum_cfg.peaks_nm, spectrum_cfg.fwhm_nm)
