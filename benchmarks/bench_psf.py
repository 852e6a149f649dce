"""Benchmark the PSF engines: a bank of 21 depths x 11 wavelengths, 2048 pupil samples, window 65 px.

Prints, for the radial engine and the 2-D (FFT) engine: build time, forward and forward+backward
seconds (gradient with respect to the radial MLP DOE's parameters), peak resident memory, and
their L1 difference (fraction of pupil energy). Each engine runs in its own process so the peak
memory is its own.

The 2-D engine takes minutes for the full bank on 2 CPU cores; ``--fourier-depths N`` runs it on
N of the 21 depths and scales the time to 21 (printed as "extrapolated").

    python benchmarks/bench_psf.py                      # full radial bank, 2-D on 3 depths
    python benchmarks/bench_psf.py --fourier-depths 21  # full 2-D bank too (slow)
    python benchmarks/bench_psf.py --engines radial --repeats 5   # the radial bank only
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time

import numpy as np
import torch

from edofproj.machine import instruction_sets

DEPTHS_M = np.linspace(0.3, 0.8, 21)
WAVELENGTHS_M = np.arange(400, 701, 30) * 1e-9


def make_doe(geometry):
    from edofproj.doe.mlp import RadialMLPDOE

    torch.manual_seed(0)
    doe = RadialMLPDOE(geometry.aperture_radius_m, frequencies=9, hidden=64, layers=3)
    with torch.no_grad():  # a non-trivial design: small random last layer
        doe.mlp[-1].weight.normal_(0, 0.5)
    return doe


def run_engine(name: str, n_depths: int, samples: int, window: int, dtype: str, repeats: int = 1) -> dict:
    from edofproj.optics.fourier_engine import FourierPSFEngine
    from edofproj.optics.geometry import ProjectorGeometry
    from edofproj.optics.radial_engine import RadialPSFEngine

    geometry = ProjectorGeometry()
    doe = make_doe(geometry)
    depths = DEPTHS_M if n_depths >= len(DEPTHS_M) else DEPTHS_M[np.linspace(0, 20, n_depths).round().astype(int)]
    torch_dtype = torch.float64 if dtype == "float64" else torch.float32
    t0 = time.perf_counter()
    cls = RadialPSFEngine if name == "radial" else FourierPSFEngine
    engine = cls(geometry, WAVELENGTHS_M, window, samples, dtype=torch_dtype)
    build = time.perf_counter() - t0

    forward, forward_backward = math.inf, math.inf  # the fastest of `repeats` runs (a loaded machine drifts)
    with torch.no_grad():
        engine.psf(doe, depths[:1])  # warm-up
        for _ in range(repeats):
            t0 = time.perf_counter()
            psf = engine.psf(doe, depths)
            forward = min(forward, time.perf_counter() - t0)

    weights = torch.rand(psf.shape, generator=torch.Generator().manual_seed(1), dtype=psf.dtype)
    for _ in range(repeats):
        doe.zero_grad()
        t0 = time.perf_counter()
        out = engine.psf(doe, depths)
        (out * weights).sum().backward()
        forward_backward = min(forward_backward, time.perf_counter() - t0)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return dict(
        engine=name,
        depths=len(depths),
        build_s=build,
        forward_s=forward,
        forward_backward_s=forward_backward,
        peak_mb=peak_mb,
        psf=psf.double().numpy().tolist(),
        depth_index=[int(np.argmin(abs(DEPTHS_M - d))) for d in depths],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=2048)
    parser.add_argument("--window", type=int, default=65)
    parser.add_argument("--fourier-depths", type=int, default=3)
    parser.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="runs per timing; the fastest is printed")
    parser.add_argument("--engines", default="radial,2d", help="comma-separated: radial, 2d")
    parser.add_argument("--child", nargs=2, metavar=("ENGINE", "DEPTHS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    if args.child:
        result = run_engine(args.child[0], int(args.child[1]), args.samples, args.window, args.dtype, args.repeats)
        print(json.dumps(result))
        return

    results = {}
    engines = [e.strip() for e in args.engines.split(",")]
    for name, n in (("radial", 21), ("2d", args.fourier_depths)):
        if name not in engines:
            continue
        cmd = [
            sys.executable,
            __file__,
            "--child",
            name,
            str(n),
            "--samples",
            str(args.samples),
            "--window",
            str(args.window),
            "--dtype",
            args.dtype,
            "--threads",
            str(args.threads),
            "--repeats",
            str(args.repeats),
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
        results[name] = json.loads(proc.stdout.strip().splitlines()[-1])

    print(
        f"PSF bank: 21 depths x {len(WAVELENGTHS_M)} wavelengths, {args.samples} pupil samples, window "
        f"{args.window} px, {args.dtype}, {args.threads} threads [{instruction_sets()}], torch {torch.__version__}, "
        f"fastest of {args.repeats} runs"
    )
    print(f"{'engine':<8} {'build s':>8} {'forward s':>10} {'fwd+bwd s':>10} {'peak MB':>8}")
    for r in results.values():
        s = 21 / r["depths"]
        note = f"  (measured on {r['depths']} depths, x{s:.1f} extrapolated)" if s > 1 else ""
        print(
            f"{r['engine']:<8} {r['build_s']:8.2f} {r['forward_s'] * s:10.2f} {r['forward_backward_s'] * s:10.2f} "
            f"{r['peak_mb']:8.0f}{note}"
        )
    if len(results) < 2:
        return
    radial, fourier = results["radial"], results["2d"]
    scale = 21 / fourier["depths"]
    a = np.asarray(radial["psf"])[fourier["depth_index"]]
    b = np.asarray(fourier["psf"])
    l1 = np.abs(a - b).sum(axis=(-1, -2))
    print(
        f"speed-up radial vs 2-D: forward {fourier['forward_s'] * scale / radial['forward_s']:.0f}x, "
        f"fwd+bwd {fourier['forward_backward_s'] * scale / radial['forward_backward_s']:.0f}x"
    )
    print(f"L1 difference (fraction of pupil energy) over {l1.size} PSFs: max {l1.max():.4f}, mean {l1.mean():.4f}")


if __name__ == "__main__":
    main()
