"""Benchmark the optics refinements: spectral sampling, lens aberrations, field-dependent PSFs.

Prints, for a design (``--doe``: a name or a saved design; default the axicon) in the ``cpu``
preset's geometry (window, pupil samples, depth range):

1. the PSF change (L1, per channel, worst depth) of each spectral sampling against a 1 nm one,
   and the cost of one PSF bank (``--depths`` depths, radial engine, one thread);
2. the aberrated engines against their closed forms (defocus = shifted focus, spherical best
   focus, Strehl ratio against Marechal);
3. how much a modest projector lens changes the design's PSFs (spherical, field curvature and
   astigmatism at the image corner);
4. the field-varying renderer at 600 x 800: its error against a brute-force sum over the PSF
   window (every source pixel's own interpolated PSF) and its time, next to ``project()``;
5. with ``--run RUN`` (a trained run), the compensated SSIM of its network when the projector's
   PSFs are the refined ones while the network is driven by the run's own PSF model.

    PYTHONPATH=src python benchmarks/bench_optics_realism.py [--doe axicon] [--depths 6] [--run RUN]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np
import torch

from edofproj.config import load_config
from edofproj.doe.factory import build_doe
from edofproj.imaging import project
from edofproj.imaging.field_varying import field_centres_px, hat_weights, project_field_varying
from edofproj.machine import instruction_sets
from edofproj.optics.aberrations import PupilAberration
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_bank import PSFSimulator
from edofproj.optics.radial_engine import RadialPSFEngine
from edofproj.optics.spectra import Spectrum, reference_spd

LAM = 550e-9


def rgb_psf(geometry, window, pupil, doe, depths, spectrum, aberration=None) -> np.ndarray:
    """RGB PSFs with all wavelengths on one radial grid (400 nm in every chunk of engines)."""
    mono = []
    lam = spectrum.wavelengths_m
    for start in range(0, len(lam), 40):
        chunk = np.concatenate([[400e-9], lam[start : start + 40]])
        engine = RadialPSFEngine(geometry, chunk, window, pupil, aberration=aberration)
        with torch.no_grad():
            mono.append(engine.psf(doe, depths)[:, 1:])
    return np.einsum("cl,zlij->zcij", spectrum.weights, torch.cat(mono, dim=1).numpy())


def l1(a: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per channel, worst depth: sum |a - ref| / sum ref."""
    return (np.abs(a - ref).sum(axis=(-1, -2)) / ref.sum(axis=(-1, -2))).max(axis=0)


def spectral(cfg, doe, depths) -> None:
    geometry = ProjectorGeometry.from_config(cfg.optics)
    base = load_config(None).spectrum
    lam, spd = reference_spd(base)
    reference = rgb_psf(geometry, cfg.psf.window, cfg.psf.pupil_samples, doe, depths, Spectrum(lam * 1e-9, spd))
    print("\n1. Spectral sampling (LED primaries 620/530/460 nm, FWHM 20/35/25 nm) against 1 nm:")
    print("| sampling | wavelengths | PSF L1 change R, G, B (worst depth) | one PSF bank (s) |")
    print("|---|---|---|---|")
    cases = [
        ("cpu preset: 460, 540, 620 nm", cfg.spectrum),
        ("30 nm over 400-700 (paper)", dataclasses.replace(base, wavelength_step_nm=30.0, trim_power=0.0)),
        ("20 nm, trimmed", dataclasses.replace(base, wavelength_step_nm=20.0)),
        ("10 nm, trimmed (default)", base),
        ("10 nm, untrimmed", dataclasses.replace(base, trim_power=0.0)),
        ("5 nm, trimmed", dataclasses.replace(base, wavelength_step_nm=5.0)),
    ]
    for name, spectrum_cfg in cases:
        spectrum = Spectrum.from_config(spectrum_cfg)
        psf = rgb_psf(geometry, cfg.psf.window, cfg.psf.pupil_samples, doe, depths, spectrum)
        sim = PSFSimulator(geometry, spectrum, cfg.psf.window, cfg.psf.pupil_samples)
        start = time.perf_counter()
        sim.bank(doe, depths)
        seconds = time.perf_counter() - start
        change = ", ".join(f"{100 * v:.3f} %" for v in l1(psf, reference))
        print(f"| {name} | {len(spectrum.wavelengths_m)} | {change} | {seconds:.2f} |")


def closed_forms(cfg) -> None:
    geometry = ProjectorGeometry.from_config(cfg.optics)
    R = geometry.aperture_radius_m
    print("\n2. Aberrated engines against closed forms (550 nm, radial engine, 1024 pupil samples):")
    c4 = 0.3e-6
    v2 = 1.0 / (1.0 / geometry.focus_distance_m - 4 * math.sqrt(3) * c4 / R**2)
    depths = np.array([0.4, 0.5, 0.6])
    a = RadialPSFEngine(geometry, [LAM], 17, 1024, aberration=PupilAberration.from_zernike_um({4: c4 * 1e6}))
    b = RadialPSFEngine(dataclasses.replace(geometry, focus_distance_m=v2), [LAM], 17, 1024)
    pa, pb = a.psf(None, depths).numpy(), b.psf(None, depths).numpy()
    print(f"   Z4 = 0.3 um vs the thin lens focused at {v2 * 1e3:.2f} mm: L1 {l1(pa, pb).max():.1e}")
    w040 = 0.1 * LAM
    ab = PupilAberration.from_zernike_um({4: w040 / (2 * math.sqrt(3)) * 1e6, 11: w040 / (6 * math.sqrt(5)) * 1e6})
    expected = -2 * w040 / R**2
    offsets = expected + np.linspace(-3e-3, 3e-3, 13)
    peak = RadialPSFEngine(geometry, [LAM], 17, 1024, aberration=ab).radial_intensity(
        None, 1 / (1 / geometry.focus_distance_m + offsets)
    )[0, :, 0]
    p = np.polyfit(offsets, peak.numpy(), 2)
    best = -p[1] / (2 * p[0])
    print(
        f"   Seidel W040 = 0.1 wave: best focus 1/z - 1/v = {best:.4e} /m, closed form {expected:.4e} /m "
        f"({100 * abs(best / expected - 1):.2f} % apart)"
    )
    ideal = RadialPSFEngine(geometry, [LAM], 17, 1024).radial_intensity(None, [geometry.focus_distance_m])[0, 0, 0]
    for waves in (0.02, 0.05, 0.1):
        eng = RadialPSFEngine(geometry, [LAM], 17, 1024, aberration=PupilAberration.from_zernike_um({11: waves * 0.55}))
        strehl = float(eng.radial_intensity(None, [geometry.focus_distance_m])[0, 0, 0] / ideal)
        print(
            f"   Z11 = {waves} wave RMS: Strehl {strehl:.5f}, Marechal exp(-(2 pi sigma)^2) "
            f"{math.exp(-((2 * math.pi * waves) ** 2)):.5f}"
        )


def lens_effects(cfg, doe, depths) -> None:
    geometry = ProjectorGeometry.from_config(cfg.optics)
    spectrum = Spectrum.from_config(load_config(None).spectrum)
    ideal = rgb_psf(geometry, cfg.psf.window, cfg.psf.pupil_samples, doe, depths, spectrum)
    print("\n3. A modest projector lens against the ideal thin lens (PSF L1 change R, G, B, worst depth):")
    cases = {
        "spherical Z11 = 0.07 wave (0.0385 um)": PupilAberration.from_zernike_um({11: 0.0385}),
        "field curvature at the corner Z4 = 0.25 wave": PupilAberration.from_zernike_um({4: 0.1375}),
        "chromatic focal shift Z4 = -0.1..+0.1 wave (460-620 nm)": PupilAberration(
            noll=(4,), coefficients_um=np.array([[-0.055, 0.055]]), wavelengths_nm=(460.0, 620.0)
        ),
    }
    for name, ab in cases.items():
        psf = rgb_psf(geometry, cfg.psf.window, cfg.psf.pupil_samples, doe, depths, spectrum, aberration=ab)
        print(f"   {name}: " + ", ".join(f"{100 * v:.2f} %" for v in l1(psf, ideal)))
    peaks = Spectrum(np.array([620e-9, 530e-9, 460e-9]), np.eye(3))  # one wavelength per primary
    sim = PSFSimulator(geometry, peaks, cfg.psf.window, 1024, engine="2d")
    two = np.array([0.4, 0.65])
    flat = sim(doe, two).numpy()
    sim.engine.aberration = PupilAberration.from_zernike_um({6: 0.1375})
    astig = sim(doe, two).numpy()
    print(
        "   astigmatism at the corner Z6 = 0.25 wave (2-D engine, 1024 samples, peak wavelengths, 400 and "
        "650 mm): " + ", ".join(f"{100 * v:.2f} %" for v in l1(astig, flat))
    )


def brute_force(image: np.ndarray, grid: np.ndarray, cy, cx) -> np.ndarray:
    """sum over window offsets of the source image times each source pixel's own PSF value."""
    C, H, W = image.shape
    K = grid.shape[-1]
    m = K // 2
    wy, wx = hat_weights(cy, H), hat_weights(cx, W)
    out = np.zeros((C, H + 2 * m, W + 2 * m))
    lost = np.zeros(C)
    for dy in range(K):
        for dx in range(K):
            value = np.einsum("iy,jx,ijc->cyx", wy, wx, grid[:, :, :, dy, dx], optimize=True)  # per-source PSF
            out[:, dy : dy + H, dx : dx + W] += image * value
    energy = np.einsum("iy,jx,ijc->cyx", wy, wx, grid.sum(axis=(-1, -2)))
    lost = (image * (1 - energy)).sum(axis=(-1, -2))
    return out[:, m : m + H, m : m + W] + (lost / (H * W))[:, None, None]


def best_time(call, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def renderer(cfg, grid_sizes=(3, 5)) -> None:
    torch.manual_seed(0)
    H, W, K = 600, 800, cfg.psf.window
    image = torch.rand(1, 3, H, W, dtype=torch.float64)
    print(f"\n4. Field-varying renderer at {H}x{W}, {K}x{K} PSFs, float64 (one thread):")
    psf = torch.rand(1, 3, K, K, dtype=torch.float64)
    psf = 0.9 * psf / psf.sum(dim=(-1, -2), keepdim=True)
    project(image, psf)  # warm-up (FFT plans)
    print(f"   project() with one PSF: {best_time(lambda: project(image, psf)):.3f} s")
    for g in grid_sizes:
        grid = torch.rand(g, g, 3, K, K, dtype=torch.float64)
        grid = 0.9 * grid / grid.sum(dim=(-1, -2), keepdim=True)
        cy = field_centres_px(np.linspace(-1 + 1 / g, 1 - 1 / g, g), H)
        cx = field_centres_px(np.linspace(-1 + 1 / g, 1 - 1 / g, g), W)
        out = project_field_varying(image, grid, cy, cx)
        seconds = best_time(lambda: project_field_varying(image, grid, cy, cx))
        ref = brute_force(image[0].numpy(), grid.numpy(), cy, cx)
        err = float(np.abs(out[0].numpy() - ref).max())
        print(f"   {g}x{g} field grid: {seconds:.3f} s (best of 3), max |error| vs brute force {err:.1e}")


def compensated_ssim(run_dir: str) -> None:
    from edofproj.data.test_images import evaluation_images
    from edofproj.metrics import ssim
    from edofproj.runs import load_run

    run = load_run(run_dir)
    cfg, net, doe = run.cfg, run.net, run.doe
    net.eval()
    geometry = ProjectorGeometry.from_config(cfg.optics)
    depths = np.array([0.3, 0.4, 0.5, 0.65, 0.8])
    window, pupil = cfg.psf.window, cfg.psf.pupil_samples
    model = PSFSimulator(geometry, Spectrum.from_config(cfg.spectrum), window, pupil)
    converged = Spectrum.from_config(load_config(None).spectrum)
    truths = {
        "the run's own PSF model": model,
        "converged spectrum (10 nm)": PSFSimulator(geometry, converged, window, pupil),
        "+ spherical Z11 = 0.07 wave": PSFSimulator(
            geometry, converged, window, pupil, aberration=PupilAberration.from_zernike_um({11: 0.0385})
        ),
        "+ defocus Z4 = 0.25 wave (field curvature at the corner)": PSFSimulator(
            geometry, converged, window, pupil, aberration=PupilAberration.from_zernike_um({4: 0.1375})
        ),
    }
    images = [t[None].float() for _, t in evaluation_images(cfg)]
    print(f"\n5. Compensated SSIM of {run_dir} ({len(images)} test images, 300/400/500/650/800 mm):")
    print("| projector's PSFs | mean SSIM | worst depth |")
    print("|---|---|---|")
    with torch.no_grad():
        p_model = model(doe, depths).float()
        for name, sim in truths.items():
            p_true = sim(doe, depths).float()
            scores = np.zeros((len(images), len(depths)))
            for i, img in enumerate(images):
                for k in range(len(depths)):
                    compensated = net(img, project(img, p_model[k : k + 1]))
                    scores[i, k] = float(ssim(project(compensated.clamp(0, 1), p_true[k : k + 1]), img))
            print(f"| {name} | {scores.mean():.4f} | {scores.mean(axis=0).min():.4f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--doe", default="axicon", help="design name or saved design (.npz)")
    parser.add_argument("--depths", type=int, default=6, help="depths per PSF bank, over the cpu preset's range")
    parser.add_argument("--skip", nargs="*", default=[], choices=["spectral", "closed", "lens", "renderer"])
    parser.add_argument("--run", default=None, help="a trained run: also measure its compensated SSIM")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_config("cpu")
    doe = build_doe(cfg, args.doe)
    depths = np.linspace(cfg.psf.depth_min_mm, cfg.psf.depth_max_mm, args.depths) * 1e-3
    print(f"design: {args.doe}; cpu preset geometry, window {cfg.psf.window}, {cfg.psf.pupil_samples} pupil samples")
    print(f"1 thread [{instruction_sets()}]")
    if "spectral" not in args.skip:
        spectral(cfg, doe, depths)
    if "closed" not in args.skip:
        closed_forms(cfg)
    if "lens" not in args.skip:
        lens_effects(cfg, doe, depths)
    if "renderer" not in args.skip:
        renderer(cfg)
    if args.run:
        compensated_ssim(args.run)


if __name__ == "__main__":
    main()
