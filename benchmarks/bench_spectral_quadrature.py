"""Benchmark spectral quadratures: each preset's spectrum and Gauss rules against a 1 nm integration.

For a preset's optics (window, pupil samples, depth range) and a design
(``--doe``: default the reference model's design ``builtin:cpu-doe-net``) at depths every
``--depth-step-mm`` over the preset's range, prints per sampling the
RGB PSF change ``sum |P - P_ref| / sum P_ref`` per channel (worst depth), the peak ratio
``max P / max P_ref`` (worst channel and depth, as a deviation from 1), the number of wavelengths
and the seconds of one PSF bank (radial engine, one thread; the machine's load shows in them).
The reference integrates the primaries' SPDs (400-700 nm) on a 1 nm grid; every sampling is
computed with all wavelengths on one radial grid (400 nm in every chunk of engines), so only the
spectral sampling differs.

    PYTHONPATH=src python benchmarks/bench_spectral_quadrature.py --preset cpu
    PYTHONPATH=src python benchmarks/bench_spectral_quadrature.py --preset paper
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import torch

from edofproj.config import load_config
from edofproj.doe.factory import build_doe
from edofproj.machine import instruction_sets
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_bank import PSFSimulator
from edofproj.optics.radial_engine import RadialPSFEngine
from edofproj.optics.spectra import Spectrum, reference_spd


def rgb_psf(geometry, cfg, doe, depths, spectrum: Spectrum) -> np.ndarray:
    """RGB PSFs (Z, C, K, K) with every wavelength on the radial grid of 400 nm."""
    mono = []
    lam = spectrum.wavelengths_m
    for start in range(0, len(lam), 40):
        chunk = np.concatenate([[400e-9], lam[start : start + 40]])
        engine = RadialPSFEngine(geometry, chunk, cfg.psf.window, cfg.psf.pupil_samples)
        with torch.no_grad():
            mono.append(engine.psf(doe, depths)[:, 1:])
    return np.einsum("cl,zlij->zcij", spectrum.weights, torch.cat(mono, dim=1).numpy())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--doe", default="builtin:cpu-doe-net")
    parser.add_argument("--depth-step-mm", type=float, default=12.5)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_config(args.preset)
    geometry = ProjectorGeometry.from_config(cfg.optics)
    doe = build_doe(cfg, args.doe)
    depths = np.arange(cfg.psf.depth_min_mm, cfg.psf.depth_max_mm + 1e-6, args.depth_step_mm) * 1e-3

    base = load_config(None).spectrum
    lam, spd = reference_spd(base)
    keep = spd.max(axis=0) > 0
    reference = rgb_psf(geometry, cfg, doe, depths, Spectrum(lam[keep] * 1e-9, spd[:, keep]))
    print(
        f"preset {args.preset}: window {cfg.psf.window}, {cfg.psf.pupil_samples} pupil samples, "
        f"{len(depths)} depths {cfg.psf.depth_min_mm:g}-{cfg.psf.depth_max_mm:g} mm, design {args.doe}; "
        f"reference: {int(keep.sum())} wavelengths (1 nm); 1 thread [{instruction_sets()}]"
    )
    print(
        "| sampling | wavelengths | PSF L1 change R, G, B (worst depth) | peak ratio - 1 (worst) | one PSF bank (s) |"
    )
    print("|---|---|---|---|---|")
    cases = [
        (f"preset {args.preset}", cfg.spectrum),
        (
            "one sample near each peak: 460, 540, 620 nm",
            dataclasses.replace(base, wavelength_min_nm=460.0, wavelength_max_nm=620.0, wavelength_step_nm=80.0),
        ),
        ("30 nm over 400-700, trimmed", dataclasses.replace(base, wavelength_step_nm=30.0)),
        ("10 nm, trimmed (the default)", base),
    ] + [
        (f"Gauss, {n} per primary", dataclasses.replace(base, quadrature="gauss", nodes_per_primary=n))
        for n in (1, 2, 3, 4)
    ]
    for name, spectrum_cfg in cases:
        spectrum = Spectrum.from_config(spectrum_cfg)
        psf = rgb_psf(geometry, cfg, doe, depths, spectrum)
        change = (np.abs(psf - reference).sum(axis=(-1, -2)) / reference.sum(axis=(-1, -2))).max(axis=0)
        peak = psf.max(axis=(-1, -2)) / reference.max(axis=(-1, -2)) - 1
        sim = PSFSimulator(geometry, spectrum, cfg.psf.window, cfg.psf.pupil_samples)
        sim.bank(doe, depths)  # warm-up
        start = time.perf_counter()
        sim.bank(doe, depths)
        seconds = time.perf_counter() - start
        print(
            f"| {name} | {len(spectrum.wavelengths_m)} | {', '.join(f'{100 * v:.3f} %' for v in change)} "
            f"| {peak.flat[np.argmax(np.abs(peak))]:+.2e} | {seconds:.2f} |"
        )


if __name__ == "__main__":
    main()
