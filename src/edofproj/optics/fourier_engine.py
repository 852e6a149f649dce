"""The general 2-D propagation engine: PSFs of any height map by a zero-padded FFT.

The pupil function g(x, y) = A(x, y) exp(i 2 pi (n - 1) h(x, y) / lambda) exp(i pi (x^2 + y^2)(1/z - 1/v) / lambda)
is point-sampled on an M x M grid of pitch dx = D / M (``pupil_samples = M``) and Fresnel-propagated
to the screen in one Fourier transform,

    U_z(x') ~ F{g}(x' / (lambda z)),

which in projector pixels (x' = x_px q(z), q = z / (T W)) is sampled at frequency x_px / (lambda T W).
An N-point FFT (N >= 2M, zero padded) gives samples spaced

    delta_px = lambda T W / (N dx)       over a field of view   FOV_px = lambda T W / dx.

By Parseval the samples' energies sum to the pupil energy. The intensity of the sampled pupil,
|U|^2, is a trigonometric polynomial of period FOV_px with frequencies up to M - 1 (cycles per
period) in each direction, so its N x N samples (N >= 2M) determine it everywhere; its integral
over a projector pixel is exact in the Fourier domain, where the pixel's box filter is the factor
sinc(k / FOV_px) on the coefficient of frequency k (:func:`.pixel_integration.periodic_pixel_weights`).
The box is separable, so the K x K pixel energies are

    E = W I W^T / (N^2 sum A),     W (K, N): W[i, n] = (p/N) sum_{|k| < M} sinc(k p/N) cos(2 pi k (i' p - n)/N),

with I the unshifted FFT samples, p = N / FOV_px the pixel in sample spacings and i' = i - K//2:
each PSF value is that pixel's exact share of the pupil energy, wherever the spot sits within it.

Sampling checks, all at once (:mod:`.sampling`: one :class:`~edofproj.errors.SamplingError` naming
the one ``pupil_samples`` that meets every requirement, the design's own rule included):
* the defocus phase step between pupil samples at the rim, 2 pi R dx |1/z - 1/v| / lambda,
  stays below pi/2;
* the FFT's periodic field of view holds the window plus the geometric blur (otherwise light
  wraps around into the window): FOV_px >= K + D |1 - z/v| / q(z);
* lens aberrations (:mod:`.aberrations`: any Zernike term, a measured wavefront map) add the
  phase 2 pi W(x, y) / lambda, whose step between pupil samples also stays below pi/2.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import EdofprojError
from ..limits import check_memory
from .aberrations import PupilAberration
from .geometry import ProjectorGeometry
from .pixel_integration import periodic_pixel_weights
from .radial_engine import (
    check_depths,
    check_pupil_samples,
    check_window,
    warn_if_blur_exceeds_window,
)
from .sampling import check_pupil_sampling


def fourier_engine_bytes(
    pupil_samples: int, window: int, n_wavelengths: int, depth_chunk: int, n_depths: int, recording: bool = False
) -> int:
    """Bytes the 2-D engine holds: about eight ``M x M`` float64 grids (coordinates, ``r^2``, the
    aperture, heights, phases), per chunk of depths the ``N x N`` complex128 FFT (``N ~ 2M``) three
    times over (field, spectrum, intensity), and the ``K x K`` PSFs of all depths (x2). While
    gradients are recorded (``recording``), autograd keeps every depth's and wavelength's spectrum
    (the exact pixel integrals depend on all of it) and pupil field for the backward pass."""
    m = int(pupil_samples)
    n = 2 * m
    grids = 8 * 8 * m * m
    fft = 16 * 3 * max(min(depth_chunk, n_depths), 1) * n * n
    kept = 16 * n_depths * n_wavelengths * (n * n + m * m) if recording else 0
    return grids + fft + kept + 8 * 2 * n_depths * n_wavelengths * window * window


class FourierPSFEngine:
    """Monochromatic pixel-integrated PSFs of any DOE on a 2-D grid (same call as the radial engine)."""

    def __init__(
        self,
        geometry: ProjectorGeometry,
        wavelengths_m,
        window: int,
        pupil_samples: int = 1024,
        dtype: torch.dtype = torch.float64,
        device=None,
        depth_chunk: int = 2,
        aberration: PupilAberration | None = None,
    ):
        #: the lens's wavefront error (None: the ideal thin lens); may be swapped between calls
        self.aberration = aberration
        self.geometry = geometry
        self.window = check_window(window)
        self.M = check_pupil_samples(pupil_samples)
        self.wavelengths_m = np.atleast_1d(np.asarray(wavelengths_m, dtype=float))
        self.dtype = dtype
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self.depth_chunk = depth_chunk

        self.dx_m = geometry.aperture_diameter_m / self.M
        check_memory(
            fourier_engine_bytes(self.M, self.window, len(self.wavelengths_m), depth_chunk, n_depths=1),
            f"the 2-D PSF engine (pupil_samples {self.M}, window {self.window} px)",
            "use fewer psf.pupil_samples (or the radial engine for a radially symmetric design)",
            device=self.device,
        )
        coords = (np.arange(self.M) - self.M / 2 + 0.5) * self.dx_m
        self.x_t = torch.as_tensor(coords, dtype=torch.float64, device=self.device)
        yy, xx = torch.meshgrid(self.x_t, self.x_t, indexing="ij")
        self.xx, self.yy = xx, yy
        self.r2 = xx**2 + yy**2
        self.aperture = self.r2 <= geometry.aperture_radius_m**2

        from scipy import fft as sfft  # here, not at import: a third of a second of every command's start

        self.fft_size: list[int] = []
        #: per wavelength, (K, N): the exact pixel integrals of the sampled intensity (module docstring)
        self.pixel_weights: list[torch.Tensor] = []
        for lam in self.wavelengths_m:
            fov_px = lam * geometry.throw_width_m / self.dx_m  # too small a field is refused by psf()
            N = sfft.next_fast_len(2 * self.M)
            pixel_cells = N / fov_px  # one pixel in FFT sample spacings; sample 0 is the axis
            centres = (np.arange(self.window) - self.window // 2) * pixel_cells
            W = periodic_pixel_weights(centres, N, self.M - 1, pixel_cells)
            self.fft_size.append(N)
            self.pixel_weights.append(torch.as_tensor(W, dtype=dtype, device=self.device))

    def _check_sampling(self, doe, depths_m) -> None:
        """Every sampling requirement at once (:mod:`.sampling`): defocus, field of view, aberration, design."""
        ab = self.aberration
        check_pupil_sampling(
            self.M,
            geometry=self.geometry,
            wavelengths_m=self.wavelengths_m,
            depths_m=depths_m,
            window=self.window,
            engine="2d",
            doe=doe,
            aberration_step_rad=None if ab is None or ab.is_zero else self.aberration_step_rad,
        )

    def aberration_step_rad(self, pupil_samples: int) -> float:
        """The aberration's largest phase step between neighbouring points, inside the aperture, of the
        ``pupil_samples`` x ``pupil_samples`` grid (all wavelengths; rows in blocks to bound memory)."""
        ab = self.aberration
        if ab is None or ab.is_zero:
            return 0.0
        m = int(pupil_samples)
        dx = self.geometry.aperture_diameter_m / m
        R = self.geometry.aperture_radius_m
        x = (torch.arange(m, dtype=torch.float64) - m / 2 + 0.5) * dx
        worst = 0.0
        block = max(1, (1 << 22) // m)
        for lam in self.wavelengths_m:
            previous = None
            for start in range(0, m, block):
                yy, xx = torch.meshgrid(x[start : start + block], x, indexing="ij")
                r2 = xx**2 + yy**2
                inside = r2 <= R**2
                phase = 2 * math.pi * ab.opd_m(torch.sqrt(r2) / R, torch.atan2(yy, xx), float(lam)) / float(lam)
                phase = torch.where(inside, phase, torch.zeros_like(phase))
                both = inside[:, 1:] & inside[:, :-1]
                worst = max(worst, float((torch.diff(phase, dim=1).abs() * both).max()))
                if previous is not None:  # the step across the block boundary
                    rows, rows_in = torch.cat([previous[0], phase]), torch.cat([previous[1], inside])
                else:
                    rows, rows_in = phase, inside
                both_y = rows_in[1:] & rows_in[:-1]
                if len(rows) > 1:
                    worst = max(worst, float((torch.diff(rows, dim=0).abs() * both_y).max()))
                previous = (phase[-1:], inside[-1:])
        return worst

    def aberration_phase(self, wavelength_m: float) -> torch.Tensor | float:
        """``2 pi W(x, y) / lambda`` on the pupil grid, (M, M), or 0 without aberration."""
        ab = self.aberration
        if ab is None or ab.is_zero:
            return 0.0
        R = self.geometry.aperture_radius_m
        rho = torch.sqrt(self.r2) / R
        theta = torch.atan2(self.yy, self.xx)
        phase = 2 * math.pi * ab.opd_m(rho, theta, wavelength_m) / wavelength_m
        return torch.where(self.aperture, phase, torch.zeros_like(phase))

    def pupil_amplitude(self, wavelength_m: float) -> torch.Tensor:
        """The pupil's amplitude A(x, y), (M, M): the aperture (1 inside, 0 outside), or a lens
        prescription's ray amplitude (``aberration.amplitude``: vignetting, absorption)."""
        ab = self.aberration
        if ab is None or not hasattr(ab, "amplitude"):
            return self.aperture.to(self.dtype)
        R = self.geometry.aperture_radius_m
        amp = ab.amplitude(torch.sqrt(self.r2) / R, torch.atan2(self.yy, self.xx), wavelength_m)
        return torch.where(self.aperture, amp, torch.zeros_like(amp)).to(self.dtype)

    def psf(self, doe, depths_m) -> torch.Tensor:
        """Pixel-integrated PSFs, (n_depths, n_lambda, K, K), fractions of the pupil energy
        (``sum A^2``: the light the lens transmits)."""
        depths_m = check_depths(depths_m)
        warn_if_blur_exceeds_window(self.geometry, depths_m, self.window)
        self._check_sampling(doe, depths_m)
        check_memory(
            fourier_engine_bytes(
                self.M,
                self.window,
                len(self.wavelengths_m),
                self.depth_chunk,
                len(depths_m),
                recording=torch.is_grad_enabled()
                and doe is not None
                and any(p.requires_grad for p in doe.parameters()),
            ),
            f"2-D PSFs at {len(depths_m)} depths (pupil_samples {self.M}, window {self.window} px)",
            "simulate fewer depths at once, or use fewer psf.pupil_samples",
            device=self.device,
        )
        if doe is None:
            height = torch.zeros_like(self.r2)
        else:
            height = doe.height_map_m(self.xx, self.yy).to(torch.float64)
            if not torch.all(torch.isfinite(height)):
                raise EdofprojError("the DOE produced NaN or infinite heights")
        z = torch.as_tensor(depths_m, dtype=torch.float64, device=self.device)
        complex_dtype = torch.complex128 if self.dtype == torch.float64 else torch.complex64
        out = []
        for li, lam in enumerate(self.wavelengths_m):
            aperture = self.pupil_amplitude(float(lam))
            pupil_energy = aperture.square().sum()
            n_minus_1 = 0.0 if doe is None else float(doe.refractive_index(lam)) - 1.0
            doe_phase = 2 * math.pi * n_minus_1 * height / lam + self.aberration_phase(float(lam))
            N = self.fft_size[li]
            W = self.pixel_weights[li]
            per_depth = []
            for start in range(0, len(depths_m), self.depth_chunk):
                zc = z[start : start + self.depth_chunk]
                defocus = (
                    math.pi * self.r2[None] * (1.0 / zc - 1.0 / self.geometry.focus_distance_m)[:, None, None] / lam
                )
                phase = (doe_phase[None] + defocus).to(self.dtype)
                field = torch.polar(aperture.expand_as(phase), phase).to(complex_dtype)
                spectrum = torch.fft.fft2(field, s=(N, N))  # unshifted: sample (0, 0) is the axis
                intensity = spectrum.real.square().addcmul_(spectrum.imag, spectrum.imag)
                per_depth.append((W @ intensity @ W.T) / (N * N * pupil_energy))
            out.append(torch.cat(per_depth, dim=0))
        return torch.stack(out, dim=1)
