"""Benchmark the engines against independent references, case by case (docs/experiments/2026-11-25-exact-pixels.md).

Prints, for each case, the PSF's L1 distance to its reference (fraction of the pupil energy, summed
over the window) and the peak ratio ``max P / max P_ref``:

1. an in-focus spot moved by a tilt onto the edge between two pixels (2-D engine, 512 samples): the
   two pixels, and the Airy pattern of the disk pupil integrated over the 7 x 7 pixels
   (Gauss-Legendre); the same for a quarter-pixel shift; the radial engine's unshifted spot;
2. a 16-level kinoform with 89 unequal rings at its exact level edges (radial engine, 1024 samples,
   window 15) against a Hankel quadrature of its piecewise-constant profile (Gauss-Legendre per
   ring, scipy's J0, cubic spline of the intensity integrated over the pixels by Gauss-Legendre);
3. the built-in cubic plate (2-D engine, 1024 samples, window 33) against the same sampled pupil
   propagated by a matrix DFT to 80 x 80 Gauss-Legendre nodes per pixel.

Only APIs that exist before and after the change are used, so the same script measures both:

    PYTHONPATH=src python benchmarks/bench_exact_pixels.py
    PYTHONPATH=OLD_CHECKOUT/src python benchmarks/bench_exact_pixels.py   # before
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch
from numpy.polynomial.legendre import leggauss
from scipy.interpolate import CubicSpline
from scipy.special import j0, j1

from edofproj.config import load_config
from edofproj.doe.factory import build_doe
from edofproj.doe.storage import TabulatedRadialDOE
from edofproj.optics.aberrations import PupilAberration
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.materials import height_2pi_m, refractive_index
from edofproj.optics.radial_engine import RadialPSFEngine

GEO = ProjectorGeometry()
R = GEO.aperture_radius_m
TW = GEO.throw_width_m


def pixel_nodes(per_pixel_sub: int = 20, order: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1/2, 1/2]: ``per_pixel_sub`` pieces of ``order`` nodes."""
    g, w = leggauss(order)
    cuts = np.linspace(-0.5, 0.5, per_pixel_sub + 1)
    half = np.diff(cuts)[:, None] / 2
    return ((cuts[:-1, None] + cuts[1:, None]) / 2 + g[None, :] * half).ravel(), (w[None, :] * half).ravel()


def integrate_radial(intensity, window: int, shift_x_px: float = 0.0) -> np.ndarray:
    """Pixel energies (K, K) of a radial intensity ``intensity(rho_px)`` centred at (shift, 0)."""
    t, w = pixel_nodes()
    c = window // 2
    out = np.empty((window, window))
    for i in range(window):
        for j in range(window):
            X, Y = np.meshgrid(t + j - c - shift_x_px, t + i - c)
            out[i, j] = np.einsum("ij,i,j->", intensity(np.hypot(X, Y)), w, w)
    return out


def airy(lam: float):
    s = lam * TW / GEO.aperture_diameter_m

    def intensity(rho_px):
        u = np.pi * np.maximum(rho_px / s, 1e-12)
        return (np.pi / 4) / s**2 * (2 * j1(u) / u) ** 2

    return intensity


def report(name: str, psf: np.ndarray, ref: np.ndarray) -> None:
    print(f"| {name} | {np.abs(psf - ref).sum():.2e} | {psf.max() / ref.max():.5f} |")


def spots() -> None:
    lam = 550e-9
    for shift in (0.5, 0.25):
        c2_m = shift * R / (2 * TW)
        engine = FourierPSFEngine(GEO, [lam], 7, 512, aberration=PupilAberration.from_zernike_um({2: c2_m * 1e6}))
        psf = engine.psf(None, [GEO.focus_distance_m])[0, 0].numpy()
        ref = integrate_radial(airy(lam), 7, shift)
        if shift == 0.5:
            print(
                f"| 2-D, spot on a pixel edge: the two pixels {psf[3, 3]:.4f} / {psf[3, 4]:.4f} (exact "
                f"{ref[3, 3]:.4f} each) | | |"
            )
        report(f"2-D, in-focus spot shifted {shift} px, vs Airy over 7x7 pixels", psf, ref)
    psf = RadialPSFEngine(GEO, [lam], 7, 1024).psf(None, [GEO.focus_distance_m])[0, 0].numpy()
    report("radial, in-focus spot vs Airy over 7x7 pixels", psf, integrate_radial(airy(lam), 7))


def kinoform() -> tuple[np.ndarray, np.ndarray]:
    lam_d = 550e-9
    r = np.sqrt(np.arange(1, 200) * lam_d * 2.0 / 8)
    edges = np.concatenate([[0.0], r[r < R - 15e-6], [R]])
    level = (-np.arange(len(edges) - 1)) % 16
    return edges, level * height_2pi_m(lam_d) / 16


def hankel_reference(edges, height, lam: float, z: float, window: int) -> np.ndarray:
    g, w = leggauss(48)
    r, wr, h = [], [], []
    for a, b, hk in zip(edges[:-1], edges[1:], height):
        cuts = np.linspace(a, b, int(np.ceil((b - a) / 20e-6)) + 1)
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            r.append((lo + hi) / 2 + g * (hi - lo) / 2)
            wr.append(w * (hi - lo) / 2)
            h.append(np.full(g.size, hk))
    r, wr, h = map(np.concatenate, (r, wr, h))
    phase = 2 * np.pi * (refractive_index(lam) - 1) * h / lam + np.pi * r**2 * (1 / z - 1 / GEO.focus_distance_m) / lam
    pupil = np.exp(1j * phase) * r * wr
    rho = np.arange(0.0, (window // 2 + 0.5) * math.sqrt(2) + 0.1, lam * TW / (2 * R) / 32)
    field = np.concatenate([j0(2 * np.pi * np.outer(part, r) / (lam * TW)) @ pupil for part in np.array_split(rho, 20)])
    return integrate_radial(
        CubicSpline(rho, np.abs(field) ** 2 * (2 * np.pi / (lam * TW)) ** 2 / (np.pi * R**2)), window
    )


def rings() -> None:
    edges, height = kinoform()
    doe = TabulatedRadialDOE(edges, height, R, 550e-9, 16)
    for lam in (460e-9, 550e-9):
        for z in (0.3, 0.5, 0.8):
            psf = RadialPSFEngine(GEO, [lam], 15, 1024).psf(doe, [z])[0, 0].numpy()
            report(
                f"radial, kinoform 89 unequal rings, {lam * 1e9:.0f} nm, {z * 1e3:.0f} mm",
                psf,
                hankel_reference(edges, height, lam, z, 15),
            )


def cubic_plate() -> None:
    cfg = load_config("cpu")
    doe = build_doe(cfg, "cubic")
    lam, M, K = 550e-9, 1024, 33
    dx = GEO.aperture_diameter_m / M
    x = (np.arange(M) - M / 2 + 0.5) * dx
    xx, yy = np.meshgrid(x, x)
    inside = xx**2 + yy**2 <= R**2
    with torch.no_grad():
        h = doe.height_map_m(torch.as_tensor(xx), torch.as_tensor(yy)).double().numpy()
    t, w = pixel_nodes(10, 8)  # 80 nodes per pixel: about 8 per cycle of the intensity
    c = K // 2
    pts = (np.arange(K)[:, None] - c + t[None, :]).ravel()  # (K * nodes,) pixel coordinates
    E = np.exp(-2j * np.pi * np.outer(pts, x) / (lam * TW))  # (P, M)
    weights = np.tile(w, K)
    for z in (0.3, 0.5, 0.8):
        engine = FourierPSFEngine(GEO, [lam], K, M)
        psf = engine.psf(doe, [z])[0, 0].numpy()
        phase = 2 * np.pi * (doe.refractive_index(lam) - 1) * h / lam
        phase = phase + np.pi * (xx**2 + yy**2) * (1 / z - 1 / GEO.focus_distance_m) / lam
        g = np.where(inside, np.exp(1j * phase), 0)
        U = E @ g @ E.T  # rows: y, columns: x
        intensity = np.abs(U) ** 2 * dx**2 / ((lam * TW) ** 2 * inside.sum())
        weighted = intensity * weights[:, None] * weights[None, :]
        ref = weighted.reshape(K, t.size, K, t.size).sum(axis=(1, 3))
        report(f"2-D, cubic plate, {z * 1e3:.0f} mm, vs matrix-DFT quadrature", psf, ref)


def main() -> None:
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    print("| case | L1 (fraction of pupil energy) | peak ratio |")
    print("|---|---|---|")
    spots()
    rings()
    cubic_plate()


if __name__ == "__main__":
    main()
