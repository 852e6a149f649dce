"""Is the real-time network as fast as FFT Wiener? Interleaved timing on this machine.

A shared 2-core virtual machine drifts by tens of percent within a minute, so timing one method
after the other (as ``edofproj bench`` does) can flip a comparison of two methods within 20 %.
This script times the methods *interleaved*: in every round each method compensates one frame,
in a rotating order, and it reports per method the median milliseconds, and per round the ratio
network / Wiener, whose median is the figure to compare with 1.

Methods: Wiener deconvolution with a cached filter (SciPy FFT and PyTorch FFT, 33x33 PSF; the
same cases as ``edofproj bench``) and the compensation network of ``--run`` (or, without
``--run``, an untrained network of the ``realtime`` preset: the cost does not depend on the
weights).

    .venv/bin/python benchmarks/bench_realtime.py --run runs/realtime [--sizes 600x800] [--rounds 200]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch

from edofproj.compensation.registry import build_network
from edofproj.config import load_config
from edofproj.evaluation import timing
from edofproj.evaluation.timing import disk_psf
from edofproj.machine import instruction_sets
from edofproj.runs import load_run


def interleaved_ms(frames: dict, rounds: int, warmup: int) -> dict[str, list[float]]:
    """Milliseconds of each frame function per round, the order rotating from round to round."""
    names = list(frames)
    for _ in range(warmup):
        for name in names:
            frames[name]()
    times = {name: [] for name in names}
    for index in range(rounds):
        shift = index % len(names)
        for name in names[shift:] + names[:shift]:
            start = time.perf_counter()
            frames[name]()
            times[name].append((time.perf_counter() - start) * 1e3)
    return times


def print_ratio_rows(times: dict[str, list[float]], reference: str, label: str) -> None:
    """One markdown row per method: ``| name | label | median ms | median per-round ratio to reference |``."""
    for name, values in times.items():
        ratio = statistics.median(v / r for v, r in zip(values, times[reference]))
        print(f"| {name} | {label} | {statistics.median(values):.1f} | {ratio:.2f} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default=None, help="a trained run directory (default: untrained realtime preset)")
    parser.add_argument("--sizes", default="600x800,768x1024", help="frame sizes HxW, comma-separated")
    parser.add_argument("--rounds", type=int, default=200, help="interleaved rounds (frames per method)")
    parser.add_argument("--warmup", type=int, default=5, help="untimed rounds first")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (PyTorch and SciPy)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    if args.run:
        trained = load_run(args.run)
        net, label, window = trained.net, trained.cfg.net.architecture, trained.cfg.psf.window
    else:
        cfg = load_config("realtime")
        net, label, window = build_network(cfg.net), f"{cfg.net.architecture} (untrained)", cfg.psf.window
    psf = disk_psf(window)
    cases = {
        "wiener/scipy": timing.wiener_scipy_case(psf, workers=args.threads),
        "wiener/torch": timing.wiener_torch_case(psf),
        f"{label}/torch": timing.network_torch_case(net, label),
    }
    network = f"{label}/torch"
    print(
        f"torch {torch.__version__}, {args.threads} thread(s) [{instruction_sets()}], {args.rounds} interleaved rounds, "
        f"ms per 3-channel frame (median; P10-P90)"
    )
    for height, width in timing.parse_sizes(args.sizes):
        frames = {name: case.build(height, width) for name, case in cases.items()}
        times = interleaved_ms(frames, args.rounds, args.warmup)
        print(f"\n{height}x{width}")
        for name, values in times.items():
            deciles = statistics.quantiles(values, n=10)
            print(f"  {name:20s} {statistics.median(values):6.2f}  ({deciles[0]:.2f}-{deciles[-1]:.2f})")
        for reference in ("wiener/scipy", "wiener/torch"):
            ratios = [n / r for n, r in zip(times[network], times[reference])]
            faster = sum(ratio <= 1 for ratio in ratios) / len(ratios)
            print(
                f"  {network} / {reference}: median ratio {statistics.median(ratios):.2f} "
                f"(network at least as fast in {100 * faster:.0f} % of rounds)"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
