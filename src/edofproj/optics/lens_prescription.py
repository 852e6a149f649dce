"""A real multi-element lens: its exit-pupil wavefront, read from a prescription through Optiland.

A projector lens is a sequence of surfaces, not a thin lens. Its prescription (a Zemax ``.zmx``
file or Optiland's own ``.json``) is read and ray traced by `Optiland <https://optiland.readthedocs.io>`_
(the optional extra ``pip install 'edofproj[lens]'``). At each field point ``(Hx, Hy)`` (the
lens's normalized field, radius 1 = its largest field) and wavelength ``lambda``, Optiland traces
a ray through every pupil sample and returns

* the optical path difference ``OPD(px, py)`` in waves, against the reference sphere centred on
  the chief ray's image point (Optiland's ``chief_ray`` strategy, the one its FFT PSF uses);
* the ray's transmitted intensity ``I(px, py)`` (0 for a ray blocked by a surface's clear
  aperture: vignetting; slightly below 1 for absorption in the glass),

over the normalized entrance-pupil coordinates ``(px, py)``, ``px^2 + py^2 <= 1``. The PSF engine
(:mod:`.fourier_engine`) then uses the pupil function

    g(x, y) = sqrt(I) exp(i 2 pi [OPD lambda + (n - 1) h(x, y)] / lambda) exp(i pi r^2 (1/z - 1/v) / lambda),

with ``(x, y) = R (px, py)``, ``R`` the entrance-pupil radius (``optics.aperture_mm`` must be the
lens's entrance-pupil diameter), the DOE's height ``h`` at the stop (imaged onto the entrance
pupil: the DOE and the lens's wavefront share the pupil coordinates) and the thin-lens defocus of
the screen depth ``z`` against the focus ``v``. The OPD is the wavefront error at the focus, so
the lens's own field curvature, astigmatism, coma and chromatic focal shift add to the depth's
defocus. The engine's wavefront is ``W = -OPD`` (Optiland's OPD in micrometres): moving the
lens's image plane (the DMD's side) away from the lens by ``delta`` gives Optiland an OPD of
``+delta NA^2 rho^2 / 2`` and corresponds to a screen beyond the focus, whose engine defocus
``r^2 (1/z - 1/v) / 2`` is negative (``tests/test_lens_prescription.py`` checks this closed form).
With this sign the engine's PSF also has Optiland's orientation (rows: ``py``, columns: ``px``).

The maps are sampled on the engine's own pupil grid (``S x S`` pixel centres spanning the pupil
diameter, ``S = psf.pupil_samples``), so the engine reads them at their nodes without
interpolation; other grids are read bilinearly. Between the tabulated wavelengths the OPD and
intensity are linear in ``lambda`` (constant beyond the ends).

The approximations shared with Optiland's own FFT PSF: the exit pupil is taken as a uniform,
undistorted image of the entrance pupil (pupil aberration ignored); the ray intensity is the
pupil amplitude squared (no obliquity factor); scalar diffraction.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError
from .aberrations import FieldAberrations, PupilAberration, _sample_map

#: prescription file suffixes and their Optiland readers
PRESCRIPTION_SUFFIXES = (".zmx", ".json")
INSTALL_HINT = "install the lens extra: pip install 'edofproj[lens]' (Optiland)"


def require_optiland():
    """The ``optiland`` package, or a one-line :class:`EdofprojError` that says how to install it."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import optiland  # noqa: F401
            import optiland.fileio
            import optiland.wavefront
    except ImportError:
        raise EdofprojError(f"a lens prescription needs Optiland, which is not installed: {INSTALL_HINT}") from None
    return optiland


def load_prescription(path: str | Path):
    """An Optiland ``Optic`` from a Zemax ``.zmx`` file or Optiland's ``.json`` (one-line errors)."""
    path = Path(path)
    if path.suffix.lower() not in PRESCRIPTION_SUFFIXES:
        raise EdofprojError(
            f"lens prescription '{path}': unknown format '{path.suffix}' (known: {', '.join(PRESCRIPTION_SUFFIXES)})"
        )
    if not path.is_file():
        raise EdofprojError(f"lens prescription '{path}' does not exist")
    optiland = require_optiland()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if path.suffix.lower() == ".zmx":
                optic = optiland.fileio.load_zemax_file(str(path))
            else:
                optic = optiland.fileio.load_optiland_file(str(path))
    except Exception as exc:  # the readers raise many types on a malformed file
        raise EdofprojError(f"cannot read lens prescription '{path}': {type(exc).__name__}: {exc}") from None
    if optic is None or not len(optic.surfaces.surfaces) >= 3:
        raise EdofprojError(f"lens prescription '{path}' holds no lens (fewer than 3 surfaces)")
    return optic


def entrance_pupil_diameter_mm(optic) -> float:
    """The lens's paraxial entrance-pupil diameter (mm, Optiland's lens units)."""
    return float(optic.paraxial.EPD())


def pupil_grid(samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalized pupil coordinates ``(px, py)``, each (S, S), at the pixel centres of ``S x S``
    samples spanning [-1, 1] (the engine's grid: ``(i - S/2 + 1/2) 2 / S``); rows are ``py``."""
    c = (np.arange(samples) - samples / 2 + 0.5) * (2.0 / samples)
    px, py = np.meshgrid(c, c)
    return px, py


def _grid_distribution(samples: int):
    """An Optiland ray distribution at the points of :func:`pupil_grid` inside the unit circle."""
    from optiland.distribution import BaseDistribution

    class _PixelCentreGrid(BaseDistribution):
        def generate_points(self, num_points: int) -> None:
            px, py = pupil_grid(num_points)
            inside = px**2 + py**2 <= 1.0
            self.x, self.y = px[inside], py[inside]

    dist = _PixelCentreGrid()
    dist.generate_points(samples)
    return dist


@dataclass(frozen=True)
class LensPupil(PupilAberration):
    """The lens's pupil at one field point: OPD (micrometres) and ray intensity maps.

    ``opd_um``, ``intensity``: (L, S, S) over the pupil grid of :func:`pupil_grid` (NaN / 0
    outside the unit circle), one map per wavelength of ``wavelengths_nm`` (L,), ascending.
    ``field_point``: the lens's normalized field point ``(Hx, Hy)``.

    It takes the place of a :class:`~.aberrations.PupilAberration` in the 2-D engine
    (``opd_m``; ``amplitude``: the pupil's amplitude ``sqrt(I)``).
    """

    opd_um: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 1)))
    intensity: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 1)))
    field_point: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        opd = np.asarray(self.opd_um, dtype=float)
        inten = np.asarray(self.intensity, dtype=float)
        if opd.ndim != 3 or opd.shape[1] != opd.shape[2] or opd.shape != inten.shape:
            raise EdofprojError(f"lens pupil maps must be (L, S, S) alike, got {opd.shape} and {inten.shape}")
        if opd.shape[0] != len(self.wavelengths_nm) or list(self.wavelengths_nm) != sorted(self.wavelengths_nm):
            raise EdofprojError("lens pupil maps need one ascending wavelength per map")
        object.__setattr__(self, "opd_um", opd)
        object.__setattr__(self, "intensity", inten)

    @property
    def is_zero(self) -> bool:  # a traced lens always has a wavefront (a 2-D map)
        return False

    @property
    def radially_symmetric(self) -> bool:
        return False

    @property
    def samples(self) -> int:
        return int(self.opd_um.shape[-1])

    def _table_at(self, table: np.ndarray, wavelength_nm: float) -> np.ndarray:
        lam = np.asarray(self.wavelengths_nm, dtype=float)
        if len(lam) == 1 or wavelength_nm <= lam[0]:
            return table[0]
        if wavelength_nm >= lam[-1]:
            return table[-1]
        k = int(np.searchsorted(lam, wavelength_nm))
        t = (wavelength_nm - lam[k - 1]) / (lam[k] - lam[k - 1])
        return (1 - t) * table[k - 1] + t * table[k]

    def opd_map_um(self, wavelength_nm: float) -> np.ndarray:
        """(S, S) OPD at ``wavelength_nm`` (micrometres; NaN outside the pupil)."""
        return self._table_at(self.opd_um, wavelength_nm)

    def rms_um(self, wavelength_nm: float) -> float:
        """Intensity-weighted RMS of the OPD about its mean (micrometres)."""
        w = self.opd_map_um(wavelength_nm)
        i = self._table_at(self.intensity, wavelength_nm)
        ok = np.isfinite(w) & (i > 0)
        mean = np.average(w[ok], weights=i[ok])
        return float(np.sqrt(np.average((w[ok] - mean) ** 2, weights=i[ok])))

    def opd_m(self, rho, theta, wavelength_m: float):
        """The OPD (metres) at normalized pupil radius ``rho`` and angle ``theta`` (tensors)."""
        if theta is None:
            raise EdofprojError("a lens prescription's wavefront is two-dimensional: use the 2-D engine (--engine 2d)")
        w = self.opd_map_um(wavelength_m * 1e9)
        return 1e-6 * _sample_map(w, rho * torch.cos(theta), rho * torch.sin(theta))

    def amplitude(self, rho, theta, wavelength_m: float):
        """The pupil amplitude ``sqrt(I)`` at ``(rho, theta)`` (0 where every ray is vignetted)."""
        i = self._table_at(self.intensity, wavelength_m * 1e9)
        sampled = _sample_map(i, rho * torch.cos(theta), rho * torch.sin(theta))  # exact at the grid's nodes
        return torch.sqrt(sampled.clamp(min=0.0))


def lens_pupil(optic, field: tuple[float, float], wavelengths_nm, samples: int) -> LensPupil:
    """Trace ``optic`` at ``field`` (normalized ``(Hx, Hy)``) for each wavelength on the
    ``samples x samples`` pupil grid: a :class:`LensPupil`."""
    require_optiland()
    from optiland.wavefront import Wavefront

    hx, hy = float(field[0]), float(field[1])
    if hx * hx + hy * hy > 1.0 + 1e-12:
        raise EdofprojError(f"lens field point ({hx:g}, {hy:g}) lies outside the lens's field (radius 1)")
    lams = sorted(float(v) for v in np.atleast_1d(wavelengths_nm))
    px, py = pupil_grid(samples)
    inside = px**2 + py**2 <= 1.0
    opd = np.full((len(lams), samples, samples), np.nan)
    inten = np.zeros((len(lams), samples, samples))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wf = Wavefront(
            optic,
            fields=[(hx, hy)],
            wavelengths=[lam / 1000.0 for lam in lams],
            num_rays=samples,
            distribution=_grid_distribution(samples),
            strategy="chief_ray",
        )
        for k, lam in enumerate(lams):
            data = wf.get_data((hx, hy), lam / 1000.0)
            o = -np.asarray(data.opd, dtype=float) * lam / 1000.0  # W = -OPD (module docstring), micrometres
            i = np.asarray(data.intensity, dtype=float)
            o = np.where(np.isfinite(o) & (i > 0), o, np.nan)
            opd[k][inside] = o
            inten[k][inside] = np.nan_to_num(i, nan=0.0)
    if not np.any(inten > 0):
        raise EdofprojError(f"every ray at lens field ({hx:g}, {hy:g}) is vignetted")
    for k in range(len(lams)):
        opd[k] = _fill_blocked(opd[k], inside)
    return LensPupil(opd_um=opd, intensity=inten, wavelengths_nm=tuple(lams), field_point=(hx, hy))


def _fill_blocked(opd: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The OPD at blocked rays inside the pupil (NaN) set to the nearest traced ray's: no light
    passes there (``I = 0``), and a continuous phase keeps the engine's sampling check (the phase
    step between neighbouring samples) about the light that does pass."""
    from scipy import ndimage

    blocked = inside & ~np.isfinite(opd)
    if not blocked.any():
        return opd
    _, (rows, cols) = ndimage.distance_transform_edt(~np.isfinite(opd), return_indices=True)
    filled = opd.copy()
    filled[blocked] = opd[rows[blocked], cols[blocked]]
    return filled


def projector_to_lens_field(field_xy, width_px: int, height_px: int) -> np.ndarray:
    """The lens's normalized field ``(Hx, Hy)`` of projector field points ``field_xy`` (P, 2) in
    [-1, 1] (x along the width, y along the height): the image's corner is the lens's full field,

        (Hx, Hy) = (x W, y H) / sqrt(W^2 + H^2).
    """
    xy = np.atleast_2d(np.asarray(field_xy, dtype=float))
    diag = math.hypot(width_px, height_px)
    return np.stack([xy[:, 0] * width_px / diag, xy[:, 1] * height_px / diag], axis=1)


def lens_field_aberrations(optic, field_xy, width_px: int, height_px: int, wavelengths_nm, samples: int):
    """:class:`~.aberrations.FieldAberrations` whose pupils are the lens's :class:`LensPupil` at the
    projector field points ``field_xy`` (P, 2) (mapped by :func:`projector_to_lens_field`), ready
    for :func:`~.field_psfs.field_psf_grid`."""
    xy = np.atleast_2d(np.asarray(field_xy, dtype=float))
    lens_xy = projector_to_lens_field(xy, width_px, height_px)
    pupils = tuple(lens_pupil(optic, (hx, hy), wavelengths_nm, samples) for hx, hy in lens_xy)
    return FieldAberrations(field_xy=xy, pupils=pupils)


def check_aperture_matches(optic, aperture_mm: float, source: str = "optics.aperture_mm") -> None:
    """Refuse an aperture that is not the lens's entrance-pupil diameter (to 0.5 %): the engine's
    pupil radius scales the DOE, the depth defocus and the lens's wavefront alike."""
    epd = entrance_pupil_diameter_mm(optic)
    if not math.isclose(float(aperture_mm), epd, rel_tol=5e-3):
        raise EdofprojError(
            f"{source}={aperture_mm:g} mm but the lens's entrance pupil is {epd:.4g} mm across: set {source}: {epd:.4g}"
        )


def lens_pupil_from_config(optics_cfg, wavelengths_m, pupil_samples: int) -> LensPupil | None:
    """The :class:`LensPupil` of an :class:`~edofproj.config.OpticsConfig`'s ``lens_prescription``
    at its ``lens_field`` for the simulator's wavelengths, on the engine's pupil grid (None: no
    prescription)."""
    path = getattr(optics_cfg, "lens_prescription", None)
    if not path:
        return None
    optic = load_prescription(path)
    check_aperture_matches(optic, optics_cfg.aperture_mm)
    field = tuple(float(v) for v in optics_cfg.lens_field)
    return lens_pupil(optic, (field[0], field[1]), np.atleast_1d(wavelengths_m) * 1e9, int(pupil_samples))
