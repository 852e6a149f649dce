"""The radial propagation engine: PSFs of rotationally symmetric pupils by a Hankel transform.

Field just after lens + DOE (on-axis pixel, paraxial), Fresnel-propagated to a screen at z:

    U_z(rho) = (2 pi / (lambda z)) * int_0^R g(r) J0(2 pi r rho / (lambda z)) r dr,
    g(r)     = exp(i 2 pi (n - 1) h(r) / lambda) * exp(i pi r^2 (1/z - 1/v) / lambda).

In projector pixels (rho = rho_px q(z), q(z) = z / (T W)) the kernel argument is
2 pi r rho_px / (lambda T W): independent of z. The pupil is split into N rings of equal
width on which g is taken constant (its value at the ring centre); each ring integral is
exact,

    int_{r_a}^{r_b} J0(2 pi f r) r dr = [r J1(2 pi f r) / (2 pi f)]_{r_a}^{r_b},   f = rho_px / (lambda T W),

so the field is one matrix product per wavelength, ``G = K_lambda g``, with ``K_lambda``
built once and cached. A design that is piecewise constant on rings of its own (a design file:
``ring_edges_m``, any widths, up to the rim) gets the equal rings split at its edges
(:meth:`RadialPSFEngine.rings_for`): its height is constant on every ring, and the transform of
its profile is exact instead of resampled at the equal rings' centres. The defocus phase alpha r^2 (alpha = pi (1/z - 1/v) / lambda) varies
inside a ring; in s = r^2 - r_m^2 (r_m the ring centre; r dr = ds / 2, so the ring's measure is
uniform in s) it is replaced by its best quadratic in the L2 sense over the ring's s-interval
[c - h, c + h], the truncated Legendre series (j_n: spherical Bessel functions, omega = alpha h),

    exp(i alpha s) ~ exp(i alpha c) [j0(omega) + 3 i j1(omega) t - 5 j2(omega) P2(t)],   t = (s - c) / h,

rewritten as b0 + b1 s + b2 s^2 per ring, depth and wavelength, with the ring moments
int s^n J0(2 pi f r) r dr (n = 0, 1, 2) in closed form: int x^3 J0 = x^3 J1 - 2 x^2 J2 and
int x^5 J0 = x^5 J1 - 4 x^4 J2 + 8 x^3 J3. The kernels stay independent of z. Being an orthogonal
projection, the quadratic never adds energy (by Parseval the PSF's energy error is the squared
residual, O(omega^6)); the Taylor polynomial 1 + i alpha s - alpha^2 s^2 / 2 it replaces gained
energy O(omega^4): 0.6 % at a defocus step of pi/2 per ring. With the normalization folded into ``K``,

    I(rho_px) = |G|^2 / ((lambda T W)^2 pi R^2)

is the fraction of the pupil energy per square pixel (Parseval: int I dA = 1 over the
whole plane). Pixel-area integration over annuli is exact (:mod:`.pixel_integration`).

Sampling: the intensity of a pupil of diameter D oscillates with period >= lambda T W / D
pixels; the radial output grid is several times finer than that (finer still near the
axis, where the in-focus Airy core is a fraction of a pixel). The pupil rings must resolve
the defocus phase: its step per ring, 2 pi R dr |1/z - 1/v| / lambda, must stay below
``MAX_DEFOCUS_STEP_RAD``; with the aberration's step and the design's own rule, every
requirement is checked at once (:mod:`.sampling`), and one
:class:`~edofproj.errors.SamplingError` names the ``pupil_samples`` that meets them all.

Lens aberrations (:mod:`.aberrations`, rotationally symmetric terms only) add the phase
``2 pi W(r) / lambda`` at the ring centres; their step per ring must stay below
``MAX_DEFOCUS_STEP_RAD`` too.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
import torch

from ..errors import BlurExceedsWindowWarning, EdofprojError
from ..limits import check_memory
from .aberrations import PupilAberration, pupil_phase_step_rad
from .geometry import ProjectorGeometry
from .pixel_integration import cubic_pixel_weights
from .sampling import MAX_PHASE_STEP_RAD, check_pupil_sampling

MAX_DEFOCUS_STEP_RAD = MAX_PHASE_STEP_RAD


def check_window(window: int) -> int:
    """A PSF window must be odd (the axis at the centre pixel) and at least 3."""
    if int(window) != window or window < 3 or window % 2 == 0:
        raise EdofprojError(f"window={window} must be an odd integer >= 3 (the optical axis sits on the centre pixel)")
    return int(window)


def check_pupil_samples(pupil_samples: int) -> int:
    """Pupil samples across the diameter: an even number >= 16."""
    if int(pupil_samples) != pupil_samples or pupil_samples < 16 or pupil_samples % 2:
        raise EdofprojError(f"pupil_samples={pupil_samples} must be an even number >= 16")
    return int(pupil_samples)


def check_depths(depths_m) -> np.ndarray:
    z = np.atleast_1d(np.asarray(depths_m, dtype=float))
    if z.size == 0 or np.any(~np.isfinite(z)) or np.any(z <= 0):
        raise EdofprojError(f"depths must be positive and finite, got {z.tolist()} m")
    return z


def warn_if_blur_exceeds_window(geometry: ProjectorGeometry, depths_m, window: int) -> None:
    blur = geometry.blur_diameter_px(depths_m)
    worst = int(np.argmax(blur))
    if blur[worst] > window:
        warnings.warn(
            f"the geometric blur disk ({blur[worst]:.1f} px at {depths_m[worst] * 1e3:.0f} mm) is wider than "
            f"the {window}-px window: the light outside is counted as haze; increase the window to keep it",
            BlurExceedsWindowWarning,
            stacklevel=3,
        )


def bessel_j123(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """J1, J2, J3 of x >= 0: scipy's fast J0/J1, upward recurrence J_{n+1} = (2n/x) J_n - J_{n-1}
    where it is stable (x > 2), and the power series below (12 terms, < 1e-16 there)."""
    from scipy.special import j0, j1  # here, not at import: a third of a second of every command's start

    x = np.asarray(x, dtype=float)
    b0, b1 = j0(x), j1(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        b2 = 2.0 / x * b1 - b0
        b3 = 4.0 / x * b2 - b1
    small = x <= 2.0
    if np.any(small):
        xs = x[small]
        for order, out in ((2, b2), (3, b3)):
            term = (xs / 2) ** order / math.factorial(order)
            total = term.copy()
            for k in range(1, 12):
                term = term * (-((xs / 2) ** 2)) / (k * (k + order))
                total += term
            out[small] = total
    return b1, b2, b3


def radial_engine_bytes(n_nu: int, n_rings: int, n_wavelengths: int, window: int, n_depths: int) -> int:
    """Bytes the radial engine holds (float64): its tables and one call for ``n_depths`` depths.

    Tables: the pixel weights ``(L, n_nu, n_unique)`` (and their NumPy original), ``n_unique =
    (h + 1)(h + 2) / 2`` pixels of one octant for ``h = K // 2``; the ring moments ``(M, 3 n_nu)``
    and about ten ``(n_nu, M + 1)`` temporaries that build them. A call: the pupil phase
    ``(L, Z, M)`` (cos, sin), the ring sums ``(L, Z, 3 n_nu)`` (x2), the intensity and its pixel
    integrals ``(L, Z, n_unique)``, the ``K x K`` PSFs (x2 for the transposed copy)."""
    half = window // 2
    n_unique = (half + 1) * (half + 2) // 2
    tables = 8 * ((n_wavelengths + 1) * n_nu * n_unique + 13 * n_rings * n_nu)
    per_depth = 8 * n_wavelengths * (3 * n_rings + 8 * n_nu + n_unique + 2 * window * window)
    return tables + n_depths * per_depth


#: design ring edges closer than this to an engine edge are merged with it (no sliver rings)
MIN_RING_M = 1e-10


def split_ring_edges(base_edges_m: np.ndarray, extra_edges_m) -> np.ndarray:
    """Sorted union of the base ring edges and ``extra_edges_m`` strictly inside them (rings
    narrower than :data:`MIN_RING_M` merged); the first and last base edges are kept."""
    base = np.asarray(base_edges_m, dtype=float)
    extra = np.asarray(extra_edges_m, dtype=float).reshape(-1)
    extra = extra[(extra > base[0]) & (extra < base[-1])]
    edges = np.unique(np.concatenate([base, extra]))
    edges = edges[np.concatenate([[True], np.diff(edges) > MIN_RING_M])]
    edges[-1] = base[-1]
    return edges


def ring_moments(ring_edges_m: np.ndarray, nu: np.ndarray, aperture_diameter_m: float) -> np.ndarray:
    """Kernel (n_rings, 3 n_nu): the ring moments int_ring s^n J0(2 pi f r) r dr (n = 0, 1, 2;
    s = r^2 - r_m^2, r_m the ring centre; f = nu / D) in closed form (module docstring), for any
    increasing ring edges (n_rings + 1,)."""
    r = np.asarray(ring_edges_m, dtype=float)[None, :]
    centres = 0.5 * (r[0, 1:] + r[0, :-1])
    c = (centres**2)[:, None]
    f = np.asarray(nu, dtype=float) / aperture_diameter_m  # spatial frequency (1/m)
    a = 2 * math.pi * np.where(f > 0, f, 1.0)[:, None]
    x = a * r
    j1_, j2, j3 = bessel_j123(x)
    p0 = r * j1_ / a  # int r J0 dr
    p1 = r**3 * j1_ / a - 2 * r**2 * j2 / a**2  # int r^3 J0 dr
    p2 = r**5 * j1_ / a - 4 * r**4 * j2 / a**2 + 8 * r**3 * j3 / a**3  # int r^5 J0 dr
    zero = f[:, None] <= 0
    p0 = np.where(zero, r**2 / 2, p0)
    p1 = np.where(zero, r**4 / 4, p1)
    p2 = np.where(zero, r**6 / 6, p2)
    d0, d1, d2 = (np.diff(p, axis=1).T for p in (p0, p1, p2))  # (n_rings, n_nu)
    return np.concatenate([d0, d1 - c * d0, d2 - 2 * c * d1 + c**2 * d0], axis=1)


def normalized_radius_grid(
    nu_max: float, fine_until: float, fine_step: float = 1 / 64, coarse_step: float = 1 / 4
) -> np.ndarray:
    """Sample radii in diffraction units nu = rho_px D / (lambda T W) (the first Airy zero is
    at nu = 1.22; the intensity oscillates with period >= 1 in nu): 1/64 up to ``fine_until``
    (the centre pixel, where the in-focus core sits), 1/4 beyond; from 0 to at least ``nu_max``.

    Measured against the closed-form Airy pattern integrated over the pixels of a 7 x 7 window
    (D = 7 mm, 550 nm, T W = 1200) with the cubic interpolation between samples: centre pixel
    within 2e-8 of the pupil energy, 5.9e-6 L1 over the window (piecewise linear: 1.0e-4, 1.5e-4)."""
    near = np.arange(0.0, min(fine_until, nu_max) + fine_step / 2, fine_step)
    far = np.arange(near[-1] + coarse_step, nu_max + coarse_step, coarse_step) if nu_max > near[-1] else np.empty(0)
    return np.concatenate([near, far])


class RadialPSFEngine:
    """Monochromatic, pixel-integrated PSFs of radial DOEs for many depths and wavelengths.

    Radii are sampled in diffraction units nu = rho_px D / (lambda T W), in which the ring
    kernel is the same for every wavelength (f = nu / D): one kernel (three ring moments)
    is built once and shared. Each wavelength has its own pixel weights (its nu grid maps to
    different pixel radii), with the intensity interpolated by cubics between samples and
    integrated over each pixel square (:func:`.pixel_integration.cubic_pixel_weights`).
    A call is two batched real matrix products for the field and one for the pixels,
    differentiable with respect to the DOE heights.
    """

    def __init__(
        self,
        geometry: ProjectorGeometry,
        wavelengths_m,
        window: int,
        pupil_samples: int = 1024,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
        aberration: PupilAberration | None = None,
    ):
        self.geometry = geometry
        self.window = check_window(window)
        self.pupil_samples = check_pupil_samples(pupil_samples)
        self.wavelengths_m = np.atleast_1d(np.asarray(wavelengths_m, dtype=float))
        self.dtype = dtype
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        #: the lens's wavefront error (None: the ideal thin lens); may be swapped between calls
        self.aberration = aberration

        R = geometry.aperture_radius_m
        D = geometry.aperture_diameter_m
        n_rings = self.pupil_samples // 2
        self.ring_edges_m = np.linspace(0.0, R, n_rings + 1)
        self.ring_centres_m = 0.5 * (self.ring_edges_m[1:] + self.ring_edges_m[:-1])
        self.ring_width_m = R / n_rings

        # radial samples: the window's corner must be covered at the shortest wavelength
        self.rho_max_px = (self.window // 2 + 0.5) * math.sqrt(2) + 0.05
        px_per_nu = self.wavelengths_m * geometry.throw_width_m / D  # (L,) pixels per diffraction unit
        self.nu = normalized_radius_grid(self.rho_max_px / px_per_nu.min(), fine_until=1.0 / px_per_nu.min())
        check_memory(
            radial_engine_bytes(len(self.nu), n_rings, len(self.wavelengths_m), self.window, n_depths=1),
            f"the radial PSF engine (window {self.window} px, pupil_samples {self.pupil_samples}, "
            f"{len(self.wavelengths_m)} wavelengths)",
            "use a smaller psf.window (the blur diameter plus a margin is enough) or fewer wavelengths",
        )  # the tables are built on the host (NumPy) first
        weights = []
        for scale in px_per_nu:
            w, index = cubic_pixel_weights(self.nu * scale, self.window)
            weights.append(w.T)
        self.pixel_weights = torch.as_tensor(np.stack(weights), dtype=dtype, device=self.device)  # (L, n_nu, n_px)
        self.pixel_index = torch.as_tensor(index.reshape(-1), device=self.device)
        # |G|^2 * norm^2 is the pupil-energy fraction per square pixel
        self.intensity_norm = torch.as_tensor(
            (2 * math.pi / (self.wavelengths_m * geometry.throw_width_m * math.sqrt(math.pi) * R)) ** 2,
            dtype=dtype,
            device=self.device,
        )[:, None, None]
        self.ring_centres_t = torch.as_tensor(self.ring_centres_m, dtype=torch.float64, device=self.device)
        self._split_rings: tuple[bytes, torch.Tensor, torch.Tensor, np.ndarray] | None = None

    @functools.cached_property
    def kernel(self) -> torch.Tensor:
        """Ring-moment kernel ``(M, 3 n_nu)`` of the engine's equal rings, built on first use: a design file
        simulates on its own rings (:meth:`rings_for`) and never needs it."""
        return torch.as_tensor(self._ring_moments(), dtype=self.dtype, device=self.device)

    @property
    def rho_px(self) -> np.ndarray:
        """Sample radii (pixels) at the first wavelength (see :meth:`rho_px_at`)."""
        return self.rho_px_at(0)

    def rho_px_at(self, wavelength_index: int) -> np.ndarray:
        lam = self.wavelengths_m[wavelength_index]
        return self.nu * lam * self.geometry.throw_width_m / self.geometry.aperture_diameter_m

    def _ring_moments(self) -> np.ndarray:
        """Kernel (M, 3 n_nu) of the engine's rings ``ring_edges_m`` (:func:`ring_moments`)."""
        return ring_moments(self.ring_edges_m, self.nu, self.geometry.aperture_diameter_m)

    def rings_for(self, doe) -> tuple[torch.Tensor, torch.Tensor]:
        """Ring centres (n,) and ring-moment kernel (n, 3 n_nu) that simulate ``doe`` exactly.

        A design that is piecewise constant on its own rings (a design file: ``ring_edges_m``,
        any widths, up to the rim) gets the engine's rings split at its edges: its height is then
        constant on every ring and each ring integral is exact. Any other design (and the bare
        lens) uses the engine's equal rings, with the height at their centres. The split kernel
        of the last design is kept (one design is simulated many times)."""
        edges = getattr(doe, "ring_edges_m", None) if doe is not None else None
        if edges is None:
            return self.ring_centres_t, self.kernel
        design = np.asarray(edges.detach().cpu().numpy() if torch.is_tensor(edges) else edges, dtype=float)
        key = design.tobytes()
        if self._split_rings is None or self._split_rings[0] != key:
            split = split_ring_edges(self.ring_edges_m, design)
            centres = torch.as_tensor(0.5 * (split[1:] + split[:-1]), dtype=torch.float64, device=self.device)
            kernel = ring_moments(split, self.nu, self.geometry.aperture_diameter_m)
            kernel_t = torch.as_tensor(kernel, dtype=self.dtype, device=self.device)
            self._split_rings = (key, centres, kernel_t, split)
        return self._split_rings[1], self._split_rings[2]

    # ------------------------------------------------------------------ physics
    def pupil_phase(self, doe, depths_m) -> tuple[torch.Tensor, torch.Tensor]:
        """Pupil phase at the ring centres of :meth:`rings_for` (rad), (n_lambda, n_depths, n_rings),
        and the defocus coefficient alpha = pi (1/z - 1/v) / lambda (rad/m^2), (n_lambda, n_depths, 1)."""
        z = torch.as_tensor(check_depths(depths_m), dtype=torch.float64, device=self.device)
        lam = torch.as_tensor(self.wavelengths_m, dtype=torch.float64, device=self.device)
        r, _ = self.rings_for(doe)
        if doe is None:
            height = torch.zeros_like(r)
            n_minus_1 = torch.zeros_like(lam)
        else:
            if not doe.radially_symmetric:
                raise EdofprojError(f"the radial engine needs a radially symmetric DOE; use --engine 2d for {doe.name}")
            height = doe.height_m(r).to(torch.float64)
            if not torch.all(torch.isfinite(height)):
                raise EdofprojError("the DOE produced NaN or infinite heights")
            n_minus_1 = torch.as_tensor(
                doe.refractive_index(self.wavelengths_m) - 1.0, dtype=torch.float64, device=self.device
            )
        doe_phase = 2 * math.pi * n_minus_1[:, None] * height[None, :] / lam[:, None]  # (L, M)
        doe_phase = doe_phase + self.aberration_phase(r)
        alpha = math.pi * (1.0 / z - 1.0 / self.geometry.focus_distance_m)[None, :, None] / lam[:, None, None]
        return doe_phase[:, None, :] + alpha * r[None, None, :] ** 2, alpha

    def aberration_phase(self, ring_centres_m: torch.Tensor | None = None) -> torch.Tensor | float:
        """``2 pi W(r_m) / lambda`` at the ring centres (default: the engine's), (n_lambda, n_rings),
        or 0 without aberration."""
        ab = self.aberration
        if ab is None or ab.is_zero:
            return 0.0
        if not ab.radially_symmetric:
            raise EdofprojError(
                "the radial engine takes only rotationally symmetric aberrations (Noll j = 1, 4, 11, 22, ...; "
                "no wavefront map): use --engine 2d"
            )
        centres = self.ring_centres_t if ring_centres_m is None else ring_centres_m
        rho = centres / self.geometry.aperture_radius_m
        return torch.stack([2 * math.pi * ab.opd_m(rho, None, float(lam)) / float(lam) for lam in self.wavelengths_m])

    def aberration_step_rad(self, pupil_samples: int) -> float:
        """The aberration's largest phase step between neighbouring ring centres of ``pupil_samples`` equal rings."""
        edges = torch.linspace(0.0, self.geometry.aperture_radius_m, pupil_samples // 2 + 1, dtype=torch.float64)
        phase = self.aberration_phase(0.5 * (edges[1:] + edges[:-1]).to(self.device))  # (L, M / 2)
        if not torch.is_tensor(phase):
            return 0.0
        return max(pupil_phase_step_rad(row[None]) for row in phase)  # along the radius, per wavelength

    def check_sampling(self, doe, depths_m) -> None:
        """Refuse (one :class:`~edofproj.errors.SamplingError` naming the one ``pupil_samples`` that meets every
        requirement: :mod:`.sampling`) rings that cannot resolve the defocus, the aberration or the design.
        A design on rings of its own is exact at any sampling (:meth:`rings_for`): its rule is not applied."""
        if doe is not None and not doe.radially_symmetric:
            raise EdofprojError(f"the radial engine needs a radially symmetric DOE; use --engine 2d for {doe.name}")
        ab = self.aberration
        if ab is not None and not ab.is_zero and not ab.radially_symmetric:
            self.aberration_phase()  # the one-line refusal of asymmetric terms
        check_pupil_sampling(
            self.pupil_samples,
            geometry=self.geometry,
            wavelengths_m=self.wavelengths_m,
            depths_m=depths_m,
            window=self.window,
            engine="radial",
            doe=doe,
            aberration_step_rad=None if ab is None or ab.is_zero else self.aberration_step_rad,
            check_design=getattr(doe, "ring_edges_m", None) is None,
        )

    def radial_intensity(self, doe, depths_m) -> torch.Tensor:
        """I at the radii ``rho_px_at(l)``: pupil-energy fraction per square pixel, (n_lambda, n_depths, n_nu)."""
        depths_m = check_depths(depths_m)
        self.check_sampling(doe, depths_m)
        phase, alpha = self.pupil_phase(doe, depths_m)
        centres, kernel = self.rings_for(doe)
        b_re, b_im, offset = self.defocus_coefficients(alpha, centres)  # (L, Z, 3, M) each: b0, b1, b2
        stacked = self._stacked_kernel(kernel)  # (3 M, n_nu): K0 over K1 over K2
        phase = phase + offset
        cos = torch.cos(phase).to(self.dtype).unsqueeze(-2)  # (L, Z, 1, M) against b (L, Z, 3, M)
        sin = torch.sin(phase).to(self.dtype).unsqueeze(-2)
        shape = b_re.shape[:-2] + (b_re.shape[-2] * b_re.shape[-1],)
        # G = sum_n (g b_n) K_n with g = cos + i sin
        # both parts in one product: the kernel (3 M x n_nu, tens of MB) is read once per pass
        parts = torch.stack([(cos * b_re - sin * b_im).reshape(shape), (sin * b_re + cos * b_im).reshape(shape)])
        re, im = torch.matmul(parts, stacked)
        return (re * re + im * im) * self.intensity_norm

    def defocus_coefficients(
        self, alpha: torch.Tensor, centres_m: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Real and imaginary parts of ``b0, b1, b2`` (L, Z, 3, M) with exp(i alpha s) ~ exp(i alpha c) (b0 + b1 s
        + b2 s^2) on each ring (module docstring), for ``alpha`` (L, Z, 1) and the rings of ``centres_m`` (M,),
        and the phase ``alpha c`` (L, Z, M) of the factor in front (c: the centre of the ring's s-interval).

        The spherical Bessel functions come from their power series, j_n(x) = x^n sum_k (-x^2/2)^k /
        (k! (2n + 2k + 1)!!) (7 terms: below 1e-13 for |x| <= pi/4, which the sampling check keeps)."""
        edges = torch.as_tensor(self._edges_for(centres_m), dtype=torch.float64, device=self.device)
        r_m = centres_m.to(torch.float64)
        s_lo, s_hi = edges[:-1] ** 2 - r_m**2, edges[1:] ** 2 - r_m**2
        c, h = 0.5 * (s_lo + s_hi), 0.5 * (s_hi - s_lo)  # (M,)
        a = alpha.to(torch.float64)  # (L, Z, 1)
        x = a * h
        y = -0.5 * x * x
        j = []
        for n in range(3):
            term = torch.ones_like(x) / math.prod(range(1, 2 * n + 2, 2))
            total = term
            for k in range(1, 7):
                term = term * y / (k * (2 * n + 2 * k + 1))
                total = total + term
            j.append(total * x**n)
        j0_, j1_, j2_ = j
        ch = c / h
        # a0 = j0, a1 = 3 i j1, a2 = -5 j2 in  b2 = 1.5 a2 / h^2,  b1 = a1 / h - 3 a2 c / h^2,
        # b0 = a0 - a1 c / h + a2 (3 c^2 / h^2 - 1) / 2
        b0 = (j0_ - 2.5 * j2_ * (3 * ch**2 - 1), -3 * j1_ * ch)
        b1 = (15 * j2_ * ch / h, 3 * j1_ / h)
        b2 = (-7.5 * j2_ / h**2, torch.zeros_like(x))
        b_re = torch.stack([b0[0], b1[0], b2[0].expand_as(b0[0])], dim=-2).to(self.dtype)
        b_im = torch.stack([b0[1], b1[1], b2[1].expand_as(b0[0])], dim=-2).to(self.dtype)
        return b_re, b_im, a * c

    def _edges_for(self, centres: torch.Tensor) -> np.ndarray:
        """Ring edges (M + 1,) of the rings whose centres :meth:`rings_for` returned."""
        if self._split_rings is not None and centres is self._split_rings[1]:
            return self._split_rings[3]
        return np.asarray(self.ring_edges_m, dtype=float)

    def _stacked_kernel(self, kernel: torch.Tensor) -> torch.Tensor:
        """``kernel`` (M, 3 n_nu) = [K0 | K1 | K2] restacked as (3 M, n_nu), kept for the last kernel."""
        cached = getattr(self, "_stacked", None)
        if cached is None or cached[0] is not kernel:
            M, n = kernel.shape[0], kernel.shape[1] // 3
            cached = (kernel, kernel.reshape(M, 3, n).transpose(0, 1).reshape(3 * M, n).contiguous())
            self._stacked = cached
        return cached[1]

    def psf(self, doe, depths_m) -> torch.Tensor:
        """Pixel-integrated PSFs, (n_depths, n_lambda, K, K); each value is a fraction of the pupil energy."""
        depths_m = check_depths(depths_m)
        warn_if_blur_exceeds_window(self.geometry, depths_m, self.window)
        check_memory(
            radial_engine_bytes(
                len(self.nu), len(self.ring_centres_m), len(self.wavelengths_m), self.window, len(depths_m)
            )
            - radial_engine_bytes(len(self.nu), len(self.ring_centres_m), len(self.wavelengths_m), self.window, 0),
            f"PSFs at {len(depths_m)} depths in a {self.window}-px window",
            "simulate fewer depths at once or use a smaller psf.window",
            device=self.device,
        )
        intensity = self.radial_intensity(doe, depths_m)  # (L, Z, n_rho)
        unique = torch.matmul(intensity, self.pixel_weights)  # (L, Z, n_unique)
        K = self.window
        full = unique[..., self.pixel_index].reshape(len(self.wavelengths_m), len(depths_m), K, K)
        return full.transpose(0, 1)
