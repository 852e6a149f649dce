"""Cross-check: the 2-D engine's PSF of a real lens against Optiland's own FFT PSF of the same lens.

Both start from Optiland's ray trace of the same prescription (OPD against the chief ray's
reference sphere, ray intensity) and differ in everything after it:

* **pupil sampling**: Optiland samples ``n x n`` points with ``linspace(-1, 1, n)`` (rim points
  included, spacing ``2/(n-1)``); the engine samples ``M x M`` pixel centres (spacing ``2/M``);
* **image sampling**: Optiland's PSF is point samples spaced ``lambda (n-1) / (G D)`` radians
  (``G``: its FFT grid; ``lambda F/# / Q`` in its image plane); the engine's is the exact
  integral over a projector pixel of ``1 / (T W)`` radians. Optiland's samples are integrated
  over each pixel here by the trapezoid rule over ``p x p`` cells (``G`` chosen per wavelength so
  that a pixel is exactly ``p`` sample spacings, ``p`` = ``--cells``);
* **normalisation**: Optiland's peak is 100 for the unaberrated pupil; both are divided here by
  their total energy (Optiland: the sum over its whole periodic grid; the engine: ``sum A^2``).

L1 = sum |engine - optiland| / sum optiland over the K x K window.

    .venv/bin/python benchmarks/lens_crosscheck.py [--lens cooke|double_gauss|FILE] [--cells 8] [--samples 128]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.lens_prescription import entrance_pupil_diameter_mm, lens_pupil, load_prescription


def sample_lens(name: str):
    """One of Optiland's example lenses (``cooke``: Cooke triplet F/5, f = 50 mm, 20 deg;
    ``double_gauss``), or a prescription file."""
    if name == "cooke":
        from optiland.samples.objectives import CookeTriplet

        return CookeTriplet()
    if name == "double_gauss":
        from optiland.samples.objectives import DoubleGauss

        return DoubleGauss()
    return load_prescription(name)


def optiland_pixel_psf(optic, field, wavelength_nm: float, rays: int, grid: int, cells: int, window: int):
    """Optiland's FFT PSF (normalized to its total) integrated over ``window x window`` pixels of
    ``cells`` sample spacings each (trapezoid rule), centred on Optiland's centre sample."""
    from optiland.psf.fft import ScalarFFTPSF

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        psf = np.asarray(ScalarFFTPSF(optic, field, wavelength_nm / 1000.0, num_rays=rays, grid_size=grid).psf)
    psf = psf / psf.sum()
    c = grid // 2  # fftshift puts the zero frequency (the chief ray's image point) here
    w = np.ones(cells + 1)
    w[0] = w[-1] = 0.5
    w /= cells
    out = np.zeros((window, window))
    half = window // 2
    for i in range(window):
        for j in range(window):
            r0 = c + (i - half) * cells - cells // 2
            c0 = c + (j - half) * cells - cells // 2
            block = psf[r0 : r0 + cells + 1, c0 : c0 + cells + 1]
            out[i, j] = w @ block @ w * cells * cells
    return out


def crosscheck(optic, fields, wavelengths_nm, samples: int = 128, cells: int = 8, window: int = 31, rays: int = 128):
    """Rows ``(field, wavelength_nm, l1, strehl_engine_peak, ...)`` comparing the engine with Optiland.

    The projector geometry is chosen so that one pixel spans ``cells`` of Optiland's samples at
    every wavelength: Optiland's grid ``G = k lambda cells`` (``k`` per micrometre; an integer)
    spaces its samples ``lambda (rays - 1) / (G D) = (rays - 1) / (k D cells)`` radians, so the
    pixel angle is ``1 / (T W) = (rays - 1) / (k D)``. ``k = 400 (rays - 1) / 127`` keeps the
    pixel at ``127 / (400 D)`` radians (0.032 mrad, 0.5 lambda/D at 550 nm for D = 10 mm) whatever
    ``rays``: ``rays`` = 128, 255, 509 give ``k`` = 400, 800, 1600."""
    epd_m = entrance_pupil_diameter_mm(optic) * 1e-3
    k = 400.0 * (rays - 1) / 127  # G / cells = k lambda[um] = 192, 220, 260 at 480, 550, 650 nm for rays = 128
    throw_width = k * 1e6 * epd_m / (rays - 1)  # T W = 1 / pixel angle (rad^-1)
    geometry = ProjectorGeometry(
        aperture_diameter_m=epd_m, focus_distance_m=1.0, throw_ratio=throw_width / 1000.0, width_px=1000, height_px=1000
    )
    rows = []
    for field in fields:
        pupil = lens_pupil(optic, field, wavelengths_nm, samples)
        engine = FourierPSFEngine(geometry, np.asarray(wavelengths_nm) * 1e-9, window, samples, aberration=pupil)
        with torch.no_grad():
            ours = engine.psf(None, [1.0])[0].numpy()  # (L, K, K)
        for li, lam in enumerate(wavelengths_nm):
            grid = k * lam / 1000.0 * cells
            if abs(grid - round(grid)) > 1e-6:
                raise ValueError(f"{lam} nm: Optiland's grid {grid} is not an integer: choose rays = 127 j + 1")
            ref = optiland_pixel_psf(optic, field, lam, rays, int(round(grid)), cells, window)
            l1 = float(np.abs(ours[li] - ref).sum() / ref.sum())
            rows.append(
                {
                    "field": tuple(field),
                    "wavelength_nm": lam,
                    "l1": l1,
                    "energy_engine": float(ours[li].sum()),
                    "energy_optiland": float(ref.sum()),
                    "peak_engine": float(ours[li].max()),
                    "peak_optiland": float(ref.max()),
                    "rms_opd_waves": pupil.rms_um(lam) / (lam / 1000.0),
                }
            )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lens", default="cooke")
    ap.add_argument("--cells", type=int, default=8, help="Optiland samples per projector pixel")
    ap.add_argument("--samples", type=int, default=128, help="the engine's pupil samples M")
    ap.add_argument("--rays", type=int, default=128, help="Optiland's pupil samples n (127 j + 1)")
    ap.add_argument("--window", type=int, default=31)
    args = ap.parse_args()
    t0 = time.perf_counter()
    optic = sample_lens(args.lens)
    rows = crosscheck(
        optic,
        [(0.0, 0.0), (0.0, 0.7), (0.0, 1.0)],
        [480.0, 550.0, 650.0],
        samples=args.samples,
        cells=args.cells,
        window=args.window,
        rays=args.rays,
    )
    print(
        "| field (Hx, Hy) | lambda (nm) | RMS OPD (waves) | L1 | energy in window engine / Optiland | peak engine / Optiland |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| ({r['field'][0]:g}, {r['field'][1]:g}) | {r['wavelength_nm']:g} | {r['rms_opd_waves']:.3f} | "
            f"{100 * r['l1']:.2f} % | {r['energy_engine']:.4f} / {r['energy_optiland']:.4f} | "
            f"{r['peak_engine']:.4f} / {r['peak_optiland']:.4f} |"
        )
    print(f"worst L1 {100 * max(r['l1'] for r in rows):.2f} %; {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
