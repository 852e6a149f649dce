"""Wavelength sampling and the RGB primaries' spectral power distributions (SPDs).

Each RGB channel's PSF is the SPD-weighted sum of monochromatic PSFs,

    PSF_c = sum_k w_ck PSF_lambda_k,   w_ck = SPD_c(lambda_k) / sum_k SPD_c(lambda_k),

over wavelengths sampled uniformly from ``wavelength_min_nm`` in ``wavelength_step_nm`` steps
up to ``wavelength_max_nm`` (the paper: 400-700 nm in 30 nm steps), then **trimmed**: the
samples at either end of the range carrying less than ``trim_power`` of every channel's power
(together, per end and channel, at most ``trim_power / 2``) are dropped and the weights
renormalized, so a converged step costs only the band where the primaries shine (the
default 10 nm over 400-700 nm keeps 24 of 31 wavelengths).

**Convergence check** (:func:`check_spectral_sampling`). A PSF pixel varies with wavelength
through the phase ``2 pi OPD / lambda`` (OPD: the largest optical path difference across the
pupil: the depth range's defocus plus one wave of DOE) and the lambda-scaling of the pattern, so its shortest
period in wavelength is about ``Lambda = lambda^2 / OPD``. The sampling's error on such a
function is its error on the SPD's characteristic function,

    e_c = max_{0 <= f <= 1/Lambda} | sum_k w_ck exp(2 pi i f lambda_k) - int SPD_c(lambda) exp(2 pi i f lambda) dlambda |,

the integral taken on the 1 nm grid. ``e_c > SPECTRAL_TOLERANCE`` warns
(:class:`~edofproj.errors.SpectralSamplingWarning`), naming the step that passes; so does a
range that cuts off part of an LED primary. Measured (docs/experiments/2026-11-23-optics-realism.md):
the default primaries need a step of 10 nm (PSFs within 0.06 % L1 of the 1 nm sampling); 20 nm
changes them by up to 0.4 %, 30 nm by 3.4 % in red.

**Gauss quadrature** (``quadrature: gauss``). A smooth function of wavelength is integrated
against one primary's SPD far better by the n-point Gauss rule of that SPD (the nodes and weights
that integrate polynomials up to degree 2n - 1 exactly against it; :func:`gauss_rule`) than by
samples on a common grid: each primary gets ``nodes_per_primary`` wavelengths of its own, and its
channel weights only those. Measured for the reference design of the ``cpu`` preset
(docs/experiments/2026-11-25-exact-pixels.md, worst of 43 depths): 2 nodes per primary (6
wavelengths) are 0.17, 0.57, 0.42 % L1 from the 1 nm integration in R, G, B, where one sample near
each peak (460, 540, 620 nm) was 5.6 % off in green. The PSFs vary with wavelength on periods of 17-33 nm, comparable to the
primaries' widths, so neither rule reaches 0.1 % with fewer than about 9 wavelengths. A
configuration that accepts a known error states it (``stated_l1_error``) and is not warned about.

The default SPDs are an assumption (the paper's measured ones are not published): three
LED-like Gaussian peaks. Measured SPDs are read from a CSV ``wavelength_nm,r,g,b``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import EdofprojError, SpectralSamplingWarning

WAVELENGTH_RANGE_NM = (350.0, 1000.0)
#: the reference grid the sampling is judged against
REFERENCE_STEP_NM = 1.0
#: largest error of the sampled SPD's characteristic function (see the module docstring)
SPECTRAL_TOLERANCE = 1e-2

#: candidate steps (nm) named by the check
CANDIDATE_STEPS_NM = (20.0, 15.0, 10.0, 8.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0)

# A configuration's spectral sampling is the same for every PSF a command computes: say so once.
warnings.filterwarnings("once", category=SpectralSamplingWarning)


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
        """The spectrum of a :class:`~edofproj.config.SpectrumConfig`: sampled and trimmed, or the
        Gauss rule of each primary (``quadrature: gauss``; module docstring)."""
        if getattr(spectrum_cfg, "quadrature", "uniform") == "gauss":
            return gauss_spectrum(spectrum_cfg)
        grid = sample_wavelengths_nm(
            spectrum_cfg.wavelength_min_nm, spectrum_cfg.wavelength_max_nm, spectrum_cfg.wavelength_step_nm
        )
        return _uniform(spectrum_cfg, grid).trimmed(getattr(spectrum_cfg, "trim_power", 0.0))

    def trimmed(self, trim_power: float) -> "Spectrum":
        """Drop end samples holding, per end and channel, at most ``trim_power / 2`` of the
        power; renormalize (wavelengths must be sorted)."""
        if trim_power <= 0 or len(self.wavelengths_m) < 2:
            return self
        head = np.cumsum(self.weights, axis=1)
        tail = np.cumsum(self.weights[:, ::-1], axis=1)[:, ::-1]
        keep = np.any(head > trim_power / 2, axis=0) & np.any(tail > trim_power / 2, axis=0)
        first, last = int(np.argmax(keep)), len(keep) - 1 - int(np.argmax(keep[::-1]))
        weights = self.weights[:, first : last + 1]
        return Spectrum(self.wavelengths_m[first : last + 1], weights / weights.sum(axis=1, keepdims=True))


def gauss_rule(wavelengths_nm, spd, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n``-point Gauss rule of the discrete measure ``sum_i spd_i delta(lambda - lambda_i)``:
    nodes (n,) in nm and weights (n,) summing to 1, with ``sum_k w_k p(x_k) = sum_i spd_i p(lambda_i)
    / sum_i spd_i`` for every polynomial ``p`` of degree <= 2n - 1.

    The three-term recurrence of the measure's orthogonal polynomials (discretized Stieltjes
    procedure, on the centred and scaled variable) gives the Jacobi matrix, whose eigenvalues are
    the nodes and the squared first components of its eigenvectors the weights (Golub-Welsch)."""
    x = np.asarray(wavelengths_nm, dtype=float)
    w = np.asarray(spd, dtype=float)
    w = w / w.sum()
    mean = float(w @ x)
    scale = float(np.sqrt(w @ (x - mean) ** 2)) or 1.0
    t = (x - mean) / scale
    if n > np.count_nonzero(w):
        raise EdofprojError(f"a {n}-point Gauss rule needs a spectrum with at least {n} wavelengths of power")
    alpha, beta = np.zeros(n), np.zeros(n)
    p_prev, p, norm_prev = np.zeros_like(t), np.ones_like(t), 1.0
    for k in range(n):
        norm = float(w @ (p * p))
        alpha[k] = float(w @ (t * p * p)) / norm
        beta[k] = norm / norm_prev if k else 0.0
        p_prev, p, norm_prev = p, (t - alpha[k]) * p - beta[k] * p_prev, norm
    off = np.sqrt(beta[1:])
    nodes, vectors = np.linalg.eigh(np.diag(alpha) + np.diag(off, 1) + np.diag(off, -1))
    return nodes * scale + mean, vectors[0] ** 2


def gauss_spectrum(spectrum_cfg) -> Spectrum:
    """``nodes_per_primary`` Gauss nodes of each primary's SPD (1 nm grid over the configured range),
    sorted; each channel weights only its own nodes: weights (C, C * n)."""
    lam, spd = reference_spd(spectrum_cfg)
    n = int(spectrum_cfg.nodes_per_primary)
    rules = [gauss_rule(lam, row, n) for row in spd]
    nodes = np.concatenate([x for x, _ in rules])
    weights = np.zeros((len(rules), nodes.size))
    for c, (_, w) in enumerate(rules):
        weights[c, c * n : (c + 1) * n] = w
    order = np.argsort(nodes)
    return Spectrum(check_wavelengths_nm(nodes[order]) * 1e-9, weights[:, order])


def reference_spd(spectrum_cfg, step_nm: float = REFERENCE_STEP_NM) -> tuple[np.ndarray, np.ndarray]:
    """The primaries' SPDs on the fine grid ``wavelength_min_nm..max`` in ``step_nm`` steps:
    ``(wavelengths_nm (n,), spd (3, n))``, each row summing to 1."""
    lam = sample_wavelengths_nm(spectrum_cfg.wavelength_min_nm, spectrum_cfg.wavelength_max_nm, step_nm)
    if spectrum_cfg.spd_csv:
        ref = Spectrum.from_csv(spectrum_cfg.spd_csv, lam)
    else:
        ref = Spectrum.led(lam, spectrum_cfg.peaks_nm, spectrum_cfg.fwhm_nm)
    return lam, ref.weights


def design_wavelength_nm(cfg) -> float:
    """The DOE's design wavelength (nm) of a configuration: ``doe.design_wavelength_nm`` where set, else the
    centroid of the primaries, ``(1/3) sum_c (sum_l l s_c(l)) / (sum_l s_c(l))`` over their SPDs
    (:func:`reference_spd`; for LED-like Gaussian peaks, the mean of ``spectrum.peaks_nm`` within their cut)."""
    if cfg.doe.design_wavelength_nm is not None:
        return float(cfg.doe.design_wavelength_nm)
    lam, spd = reference_spd(cfg.spectrum)
    return float(np.mean(spd @ lam / spd.sum(axis=1)))


def pupil_path_difference_m(geometry, cfg) -> float:
    """The largest optical path difference across the pupil for a config's depth range: the
    defocus ``R^2 max|1/z - 1/v| / 2`` plus one wave of DOE at the design wavelength."""
    z = np.array([cfg.psf.depth_min_mm, cfg.psf.depth_max_mm]) * 1e-3
    defocus = geometry.aperture_radius_m**2 * float(np.max(np.abs(1 / z - 1 / geometry.focus_distance_m))) / 2
    return defocus + design_wavelength_nm(cfg) * 1e-9


def shortest_spectral_period_nm(wavelength_nm: float, path_difference_m: float) -> float:
    """``Lambda = lambda^2 / OPD``: the shortest period in wavelength of a PSF pixel when the
    largest optical path difference across the pupil is ``path_difference_m``."""
    opd_nm = max(float(path_difference_m) * 1e9, float(wavelength_nm))  # at least one wave
    return float(wavelength_nm) ** 2 / opd_nm


def characteristic_error(spectrum: Spectrum, reference_nm, reference_spd, periods_nm) -> np.ndarray:
    """Per channel, the largest error of the sampled SPD's characteristic function against the
    reference ``(wavelengths_nm (n,), spd (C, n))``, over frequencies ``0..1/periods_nm[c]``."""
    lam = spectrum.wavelengths_m * 1e9
    ref_lam = np.asarray(reference_nm, dtype=float)
    errors = []
    for c in range(spectrum.n_channels):
        f = np.linspace(0.0, 1.0 / periods_nm[c], 33)[:, None]
        sampled = np.exp(2j * math.pi * f * lam[None, :]) @ spectrum.weights[c]
        exact = np.exp(2j * math.pi * f * ref_lam[None, :]) @ reference_spd[c]
        errors.append(float(np.max(np.abs(sampled - exact))))
    return np.asarray(errors)


def needed_sampling(spectrum_cfg, path_difference_m: float) -> str:
    """The largest of :data:`CANDIDATE_STEPS_NM` that passes :func:`check_spectral_sampling`."""
    lam, spd = reference_spd(spectrum_cfg)
    periods = _channel_periods(lam, spd, path_difference_m)
    for step in CANDIDATE_STEPS_NM:
        grid = sample_wavelengths_nm(spectrum_cfg.wavelength_min_nm, spectrum_cfg.wavelength_max_nm, step)
        try:
            sampled = _uniform(spectrum_cfg, grid)
        except EdofprojError:
            continue
        if np.all(characteristic_error(sampled, lam, spd, periods) <= SPECTRAL_TOLERANCE):
            return f"spectrum.wavelength_step_nm <= {step:g}"
    return "spectrum.wavelength_step_nm <= 1"


def check_spectral_sampling(spectrum_cfg, spectrum: Spectrum, path_difference_m: float) -> np.ndarray:
    """Warn (:class:`~edofproj.errors.SpectralSamplingWarning`) when ``spectrum`` undersamples a
    primary for PSFs whose largest pupil path difference is ``path_difference_m`` (module
    docstring); returns the per-channel errors."""
    lam, spd = reference_spd(spectrum_cfg)
    if spectrum.n_channels != len(spd):
        return np.zeros(spectrum.n_channels)
    stated = float(getattr(spectrum_cfg, "stated_l1_error", 0.0) or 0.0)
    cut = covering_range_nm(spectrum_cfg)
    if cut is not None:
        warnings.warn(
            f"spectrum.wavelength_min_nm-wavelength_max_nm ({spectrum_cfg.wavelength_min_nm:g}-"
            f"{spectrum_cfg.wavelength_max_nm:g} nm) cuts off part of a primary's spectrum: PSFs are off by more "
            f"than 0.1 % L1; use {cut[0]:g}-{cut[1]:g} nm",
            SpectralSamplingWarning,
            stacklevel=3,
        )
        return np.full(spectrum.n_channels, np.inf)
    errors = characteristic_error(spectrum, lam, spd, _channel_periods(lam, spd, path_difference_m))
    if np.any(errors > SPECTRAL_TOLERANCE) and stated <= 0:
        worst = int(np.argmax(errors))
        names = ("red", "green", "blue") if len(errors) == 3 else tuple(str(i) for i in range(len(errors)))
        warnings.warn(
            f"the spectrum sampling undersamples the {names[worst]} primary (error {errors[worst]:.1e} > "
            f"{SPECTRAL_TOLERANCE:g} for a {path_difference_m * 1e6:.1f} um pupil path difference): PSFs are off "
            f"by more than 0.1 % L1; use {needed_sampling(spectrum_cfg, path_difference_m)}"
            + (
                " with spectrum.quadrature=uniform"
                if getattr(spectrum_cfg, "quadrature", "uniform") != "uniform"
                else ""
            )
            + " (or state the accepted error in spectrum.stated_l1_error)",
            SpectralSamplingWarning,
            stacklevel=3,
        )
    return errors


def covering_range_nm(spectrum_cfg, lost_power: float = 1e-3) -> tuple[float, float] | None:
    """For the LED model, a 10 nm-rounded range holding all but ``lost_power`` of each primary
    when the configured range does not (None when it does, or for measured SPDs)."""
    if spectrum_cfg.spd_csv:
        return None
    lo_nm, hi_nm = WAVELENGTH_RANGE_NM
    lam = sample_wavelengths_nm(lo_nm, hi_nm, REFERENCE_STEP_NM)
    spd = Spectrum.led(lam, spectrum_cfg.peaks_nm, spectrum_cfg.fwhm_nm).weights
    inside = (lam >= spectrum_cfg.wavelength_min_nm) & (lam <= spectrum_cfg.wavelength_max_nm)
    if np.all(spd[:, inside].sum(axis=1) >= 1 - lost_power):
        return None
    cum = np.cumsum(spd, axis=1)
    first = min(float(lam[int(np.searchsorted(row, lost_power / 2))]) for row in cum)
    last = max(float(lam[min(int(np.searchsorted(row, 1 - lost_power / 2)), len(lam) - 1)]) for row in cum)
    return float(np.floor(first / 10) * 10), float(np.ceil(last / 10) * 10)


def _channel_periods(lam_nm: np.ndarray, spd: np.ndarray, path_difference_m: float) -> np.ndarray:
    """Per channel, ``Lambda`` at the channel's shortest wavelength holding 0.1 % of its power."""
    lows = [lam_nm[np.searchsorted(np.cumsum(row), 1e-3)] for row in spd]
    return np.array([shortest_spectral_period_nm(lo, path_difference_m) for lo in lows])


def _uniform(spectrum_cfg, grid_nm: np.ndarray) -> Spectrum:
    if spectrum_cfg.spd_csv:
        return Spectrum.from_csv(spectrum_cfg.spd_csv, grid_nm)
    return Spectrum.led(grid_nm, spectrum_cfg.peaks_nm, spectrum_cfg.fwhm_nm)
