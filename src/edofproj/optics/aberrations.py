"""Lens aberrations: a wavefront error W (optical path difference, metres) added to the pupil.

The ideal thin lens focuses a point at ``v`` perfectly; a real projector lens adds a wavefront
error ``W(rho, theta; field, lambda)`` over the normalized pupil (``rho = r / R``), which enters
both engines as the extra pupil phase

    phi_ab = 2 pi W / lambda.

``W`` is given as Zernike coefficients in micrometres of OPD, **Noll-indexed and RMS-normalized**
(Noll 1976: ``j = 1`` piston, 2/3 tilt, 4 defocus, 5/6 astigmatism, 7/8 coma, 11 primary
spherical, ...), so the RMS wavefront error is ``sigma = sqrt(sum_{j >= 2} c_j^2)``:

    Z_j(rho, theta) = sqrt(n + 1) R_n^m(rho)                       (m = 0)
                    = sqrt(2 (n + 1)) R_n^m(rho) cos(m theta)      (m != 0, j even)
                    = sqrt(2 (n + 1)) R_n^m(rho) sin(m theta)      (m != 0, j odd)

with ``R_n^m(rho) = sum_s (-1)^s (n - s)! / (s! ((n + m)/2 - s)! ((n - m)/2 - s)!) rho^(n - 2 s)``,
``theta`` measured from the +x axis (the projector image's width) and ``+y`` along its height.
The coefficients may depend on the wavelength (a table: linear interpolation in lambda, constant
beyond its ends -- chromatic focal shift is a wavelength-dependent ``Z4``) and on the field point
(:class:`FieldAberrations`: one :class:`PupilAberration` per field point).

A measured wavefront map (``.npy``, micrometres, a square array spanning the aperture diameter,
NaN outside the pupil allowed) replaces or adds to the Zernike terms (2-D engine only).

Closed forms used by the tests (docs/physics.md "Lens aberrations"):

* ``Z4 = sqrt(3) (2 rho^2 - 1)``: a coefficient ``c4`` is the thin-lens defocus
  ``pi r^2 (1/z - 1/v) / lambda`` with ``1/z - 1/v = 4 sqrt(3) c4 / R^2``: a shifted focus;
* Seidel spherical ``W040 rho^4 = W040 (Z11 / (6 sqrt 5) + Z4 / (2 sqrt 3)) + const``: its best
  focus (least RMS) cancels the ``Z4`` part, ``1/z - 1/v = -2 W040 / R^2``;
* small aberrations: Strehl ratio ``~ exp(-(2 pi sigma / lambda)^2)`` (Marechal).

Only rotationally symmetric terms (``m = 0``: ``j = 1, 4, 11, 22, 37, ...``) fit the radial engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError, SamplingError
from ..fileio import read_single_numeric_array


def noll_to_nm(j: int) -> tuple[int, int]:
    """Radial order ``n`` and signed azimuthal order ``m`` of Noll index ``j >= 1``
    (``m > 0``: cosine term, ``m < 0``: sine term)."""
    if int(j) != j or j < 1:
        raise EdofprojError(f"Noll index {j} must be an integer >= 1")
    j = int(j)
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    k = j - n * (n + 1) // 2 - 1  # position within the radial order, 0..n
    m = (k + 1) // 2 * 2 if n % 2 == 0 else k // 2 * 2 + 1
    sign = 1 if (m == 0 or j % 2 == 0) else -1
    return n, sign * m


def radial_polynomial(n: int, m: int, rho):
    """``R_n^|m|(rho)`` (works on numpy arrays and torch tensors)."""
    m = abs(m)
    total = 0.0 * rho
    for s in range((n - m) // 2 + 1):
        coef = (-1) ** s * math.factorial(n - s)
        coef /= math.factorial(s) * math.factorial((n + m) // 2 - s) * math.factorial((n - m) // 2 - s)
        total = total + coef * rho ** (n - 2 * s)
    return total


def zernike(j: int, rho, theta=None):
    """RMS-normalized Noll Zernike ``Z_j(rho, theta)`` (module docstring); ``theta`` may be
    None for ``m = 0`` terms."""
    n, m = noll_to_nm(j)
    radial = radial_polynomial(n, m, rho)
    if m == 0:
        return math.sqrt(n + 1) * radial
    if theta is None:
        raise EdofprojError(f"Zernike Z{j} is not rotationally symmetric: it needs the pupil angle")
    angle = abs(m) * theta
    if isinstance(angle, torch.Tensor):
        trig = torch.sin(angle) if m < 0 else torch.cos(angle)
    else:
        trig = np.sin(angle) if m < 0 else np.cos(angle)
    return math.sqrt(2 * (n + 1)) * radial * trig


def is_rotationally_symmetric(j: int) -> bool:
    return noll_to_nm(j)[1] == 0


@dataclass(frozen=True)
class PupilAberration:
    """The wavefront error at one field point.

    ``noll``: (J,) Noll indices; ``coefficients_um``: (J, n_table) micrometres of OPD at the
    table wavelengths ``wavelengths_nm`` (n_table,) (one column: the same at every wavelength);
    ``wavefront_map_um``: optional (S, S) measured OPD across the aperture diameter.
    """

    noll: tuple[int, ...] = ()
    coefficients_um: np.ndarray = field(default_factory=lambda: np.zeros((0, 1)))
    wavelengths_nm: tuple[float, ...] = (550.0,)
    wavefront_map_um: np.ndarray | None = None

    def __post_init__(self) -> None:
        coef = np.atleast_2d(np.asarray(self.coefficients_um, dtype=float))
        if coef.shape[0] != len(self.noll) and coef.size:
            raise EdofprojError(f"{len(self.noll)} Zernike indices but coefficients of shape {coef.shape}")
        if coef.size and coef.shape[1] != len(self.wavelengths_nm):
            raise EdofprojError(f"Zernike table: {coef.shape[1]} columns but {len(self.wavelengths_nm)} wavelengths")
        if not np.all(np.isfinite(coef)):
            raise EdofprojError("Zernike coefficients must be finite")
        for j in self.noll:
            noll_to_nm(j)
        object.__setattr__(self, "coefficients_um", coef.reshape(len(self.noll), len(self.wavelengths_nm)))
        if self.wavefront_map_um is not None:
            w = np.asarray(self.wavefront_map_um, dtype=float)
            if w.ndim != 2 or w.shape[0] != w.shape[1] or w.shape[0] < 2:
                raise EdofprojError(f"a wavefront map must be a square 2-D array, got shape {w.shape}")
            object.__setattr__(self, "wavefront_map_um", w)

    @classmethod
    def from_zernike_um(cls, coefficients: dict) -> "PupilAberration":
        """The same Noll coefficients (micrometres) at every wavelength: ``{j: c_j}``."""
        items = sorted((int(j), float(c)) for j, c in coefficients.items())
        return cls(noll=tuple(j for j, _ in items), coefficients_um=np.array([[c] for _, c in items]).reshape(-1, 1))

    @property
    def is_zero(self) -> bool:
        return not np.any(self.coefficients_um) and self.wavefront_map_um is None

    @property
    def radially_symmetric(self) -> bool:
        active = [j for j, row in zip(self.noll, self.coefficients_um) if np.any(row)]
        return self.wavefront_map_um is None and all(is_rotationally_symmetric(j) for j in active)

    def coefficients_at_um(self, wavelength_nm: float) -> np.ndarray:
        """(J,) coefficients at ``wavelength_nm`` (linear in lambda, constant beyond the table)."""
        lam = np.asarray(self.wavelengths_nm, dtype=float)
        if len(lam) == 1:
            return self.coefficients_um[:, 0]
        order = np.argsort(lam)
        return np.array([np.interp(wavelength_nm, lam[order], row[order]) for row in self.coefficients_um])

    def rms_um(self, wavelength_nm: float) -> float:
        """RMS wavefront error of the Zernike terms (piston excluded), micrometres."""
        c = self.coefficients_at_um(wavelength_nm)
        return float(np.sqrt(sum(ci**2 for j, ci in zip(self.noll, c) if j != 1)))

    def opd_m(self, rho, theta, wavelength_m: float):
        """The wavefront error (metres) at normalized pupil radius ``rho`` and angle ``theta``
        (tensors of one shape; ``theta`` None for symmetric terms)."""
        c = self.coefficients_at_um(wavelength_m * 1e9)
        total = 0.0 * rho
        for j, cj in zip(self.noll, c):
            if cj != 0.0:
                total = total + cj * 1e-6 * zernike(j, rho, theta)
        if self.wavefront_map_um is not None:
            if theta is None:
                raise EdofprojError("a measured wavefront map is two-dimensional: use the 2-D engine (--engine 2d)")
            total = total + 1e-6 * _sample_map(self.wavefront_map_um, rho * torch.cos(theta), rho * torch.sin(theta))
        return total


def _sample_map(wavefront_um: np.ndarray, x, y):
    """Bilinear samples of a square map spanning [-1, 1]^2 (pixel centres) at normalized (x, y).
    NaN entries (outside the measured pupil) are left out and the remaining corners' weights
    renormalized, so the rim reads the measured values; a cell with no measured corner reads 0."""
    valid = torch.as_tensor(np.isfinite(wavefront_um), dtype=torch.float64, device=x.device)
    w = torch.as_tensor(np.nan_to_num(wavefront_um, nan=0.0), dtype=torch.float64, device=x.device)
    S = w.shape[0]
    u = ((x + 1) * S / 2 - 0.5).clamp(0, S - 1)  # column
    v = ((y + 1) * S / 2 - 0.5).clamp(0, S - 1)  # row
    u0, v0 = u.floor().long().clamp(max=S - 2), v.floor().long().clamp(max=S - 2)
    fu, fv = u - u0, v - v0
    total, weight = 0.0 * x, 0.0 * x
    for dv, du, b in ((0, 0, (1 - fu) * (1 - fv)), (0, 1, fu * (1 - fv)), (1, 0, (1 - fu) * fv), (1, 1, fu * fv)):
        m = valid[v0 + dv, u0 + du] * b
        total = total + m * w[v0 + dv, u0 + du]
        weight = weight + m
    return torch.where(weight > 0, total / weight.clamp(min=1e-300), torch.zeros_like(total))


def pupil_phase_step_rad(phase: torch.Tensor) -> float:
    """The largest phase step (rad) between neighbouring pupil samples along the last axis
    (and the one before, for a 2-D map), inside the aperture."""
    steps = [torch.diff(phase, dim=-1).abs().max()] if phase.shape[-1] > 1 else []
    if phase.ndim >= 2 and phase.shape[-2] > 1:
        steps.append(torch.diff(phase, dim=-2).abs().max())
    return float(max(steps)) if steps else 0.0


def check_aberration_sampling(step_rad: float, pupil_samples: int, per: str, max_step_rad: float) -> None:
    """Refuse an aberration whose phase changes by more than ``max_step_rad`` between neighbouring pupil
    samples (``per``: "sample" or "ring"), naming the ``pupil_samples`` that resolve it."""
    if step_rad > max_step_rad:
        need = int(math.ceil(pupil_samples * step_rad / max_step_rad))
        raise SamplingError(
            f"pupil_samples={pupil_samples} cannot resolve the aberration phase ({step_rad:.2f} rad per {per}, "
            f"max {max_step_rad:.2f}): use pupil_samples >= {need + need % 2}"
        )


@dataclass(frozen=True)
class FieldAberrations:
    """Aberrations at a set of field points: ``field_xy`` (P, 2), each in [-1, 1] (x: along the
    image width, -1 the left edge; y: along the height, -1 the top edge), and one
    :class:`PupilAberration` per point."""

    field_xy: np.ndarray
    pupils: tuple[PupilAberration, ...]

    @classmethod
    def from_csv(cls, path: str | Path) -> "FieldAberrations":
        """A table with columns ``field_x,field_y,wavelength_nm,noll,coefficient_um`` (header
        optional). Every field point needs the same wavelengths; missing (index, wavelength)
        pairs are zero."""
        try:
            table = np.atleast_2d(np.genfromtxt(path, delimiter=",", comments="#", dtype=float))
        except (OSError, ValueError) as exc:
            raise EdofprojError(f"cannot read aberration table '{path}': {exc}") from None
        table = table[np.all(np.isfinite(table), axis=1)] if table.size else table
        if table.ndim != 2 or table.shape[1] != 5 or table.shape[0] < 1:
            raise EdofprojError(
                f"aberration table '{path}' must have rows 'field_x,field_y,wavelength_nm,noll,coefficient_um'"
            )
        if np.any(np.abs(table[:, :2]) > 1):
            raise EdofprojError(f"aberration table '{path}': field_x and field_y must be in [-1, 1]")
        if np.any(table[:, 3] != np.round(table[:, 3])) or np.any(table[:, 3] < 1):
            raise EdofprojError(f"aberration table '{path}': noll must be an integer >= 1")
        points = np.unique(table[:, :2], axis=0)
        lams = tuple(np.unique(table[:, 2]).tolist())
        nolls = tuple(int(j) for j in np.unique(table[:, 3]))
        pupils = []
        for p in points:
            rows = table[np.all(table[:, :2] == p, axis=1)]
            coef = np.zeros((len(nolls), len(lams)))
            for _, _, lam, j, c in rows:
                coef[nolls.index(int(j)), lams.index(lam)] = c
            pupils.append(PupilAberration(noll=nolls, coefficients_um=coef, wavelengths_nm=lams))
        return cls(field_xy=points, pupils=tuple(pupils))


def load_wavefront_map_um(path: str | Path) -> np.ndarray:
    """A measured wavefront map (``.npy``, micrometres of OPD, square, spanning the aperture)."""
    w = read_single_numeric_array(path, "wavefront map", f"wavefront map '{path}'", "it must hold one square 2-D array")
    if w.ndim != 2 or w.shape[0] != w.shape[1] or w.shape[0] < 2:
        raise EdofprojError(f"wavefront map '{path}' must be a square 2-D array, got shape {w.shape}")
    if np.all(np.isnan(w)) or np.any(np.isinf(w)):
        raise EdofprojError(f"wavefront map '{path}' has no finite values or infinite ones")
    return w.astype(float)


def aberration_from_config(optics_cfg) -> PupilAberration | None:
    """The on-axis aberration of an :class:`~edofproj.config.OpticsConfig` (``zernike_um`` and
    ``wavefront_map``), or None for the ideal thin lens. Per-field tables
    (``aberration_csv``) are read by :func:`field_aberrations_from_config`."""
    zern = dict(getattr(optics_cfg, "zernike_um", {}) or {})
    path = getattr(optics_cfg, "wavefront_map", None)
    if not zern and not path:
        return None
    base = PupilAberration.from_zernike_um(zern)
    if path:
        base = PupilAberration(
            noll=base.noll,
            coefficients_um=base.coefficients_um,
            wavelengths_nm=base.wavelengths_nm,
            wavefront_map_um=load_wavefront_map_um(path),
        )
    return base


def field_aberrations_from_config(optics_cfg) -> FieldAberrations | None:
    path = getattr(optics_cfg, "aberration_csv", None)
    return FieldAberrations.from_csv(path) if path else None
