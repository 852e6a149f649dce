"""Benchmark the radial engine's field computation: the Legendre defocus coefficients against the former
Taylor ones, on the same engine, design and matrices, interleaved in one process (a loaded machine's
drift affects both alike).

The former formula: ``G = K0 g + i alpha K1 g - alpha^2 / 2 K2 g`` from two products
``(L, Z, M) @ (M, 3 n_nu)``; the current one (:meth:`RadialPSFEngine.radial_intensity`): the
per-ring coefficients ``b0, b1, b2`` and two products ``(L, Z, 3 M) @ (3 M, n_nu)``. Prints min and
median seconds of the forward pass and of forward and backward (the bench_psf bank: 21 depths x 11
wavelengths, 2048 pupil samples, window 65 px, float32, 2 threads).

    PYTHONPATH=src python benchmarks/bench_radial_defocus.py
"""

from __future__ import annotations

import time

import numpy as np
import torch

from edofproj.doe.mlp import RadialMLPDOE
from edofproj.machine import instruction_sets
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.radial_engine import RadialPSFEngine

DEPTHS_M = np.linspace(0.3, 0.8, 21)  # as in bench_psf.py
WAVELENGTHS_M = np.arange(400, 701, 30) * 1e-9


def make_doe(geometry):
    """bench_psf.py's design: the radial MLP with a small random last layer."""
    torch.manual_seed(0)
    doe = RadialMLPDOE(geometry.aperture_radius_m, frequencies=9, hidden=64, layers=3)
    with torch.no_grad():
        doe.mlp[-1].weight.normal_(0, 0.5)
    return doe


def main() -> None:
    torch.set_num_threads(2)
    geometry = ProjectorGeometry()
    doe = make_doe(geometry)
    engine = RadialPSFEngine(geometry, WAVELENGTHS_M, 65, 2048, dtype=torch.float32)

    def taylor(doe, depths):
        phase, alpha = engine.pupil_phase(doe, depths)
        n = len(engine.nu)
        cos_k = torch.matmul(torch.cos(phase).to(engine.dtype), engine.kernel)
        sin_k = torch.matmul(torch.sin(phase).to(engine.dtype), engine.kernel)
        a = alpha.to(engine.dtype)
        re = cos_k[..., :n] - a * sin_k[..., n : 2 * n] - 0.5 * a * a * cos_k[..., 2 * n :]
        im = sin_k[..., :n] + a * cos_k[..., n : 2 * n] - 0.5 * a * a * sin_k[..., 2 * n :]
        return (re * re + im * im) * engine.intensity_norm

    methods = {"Taylor (former)": taylor, "Legendre (current)": engine.radial_intensity}
    forward = {name: [] for name in methods}
    both = {name: [] for name in methods}
    for _ in range(16):
        for name, fn in methods.items():
            with torch.no_grad():
                start = time.perf_counter()
                fn(doe, DEPTHS_M)
                forward[name].append(time.perf_counter() - start)
    for _ in range(6):
        for name, fn in methods.items():
            doe.zero_grad()
            start = time.perf_counter()
            torch.matmul(fn(doe, DEPTHS_M), engine.pixel_weights).sum().backward()
            both[name].append(time.perf_counter() - start)
    print(f"2 threads [{instruction_sets()}]")
    for name in methods:
        print(
            f"{name:<20} forward: min {min(forward[name]):.3f} s, median {np.median(forward[name]):.3f} s; "
            f"forward+backward: min {min(both[name]):.3f} s, median {np.median(both[name]):.3f} s"
        )


if __name__ == "__main__":
    main()
