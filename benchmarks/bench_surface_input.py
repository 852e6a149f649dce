"""Cost per frame of the surface input (``net.surface_input``): the network of a config, plain and wrapped.

For a preset's network (default ``cpu``) prints the median milliseconds of one compensated frame
(batch 1, ``torch.inference_mode``, CPU) of

* the plain network ``f(I, I*)``;
* ``SurfaceAwareNet(f)`` given a reflectance and ambient: the division, ``f`` and the surface head;
* the photometric-only baseline ``clip((G - a) / s, 0, 1)``;

and the difference (the extra input's cost). Weights do not matter for the time (the linear base
of the ``cpu`` preset is left at its untrained identity kernel of the same size).

    nice .venv/bin/python benchmarks/bench_surface_input.py [--config cpu] [--sizes 600x800] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from edofproj.compensation.photometric import photometric_compensation
from edofproj.compensation.registry import build_network
from edofproj.compensation.surface_net import SurfaceAwareNet
from edofproj.config import load_config
from edofproj.machine import instruction_sets


def interleaved_median_ms(runs, warmup: int, repeats: int) -> list[float]:
    """Median ms of each callable, timed in turn within every repeat (a loaded machine's drift hits all alike)."""
    for _ in range(warmup):
        for run in runs:
            run()
    times: list[list[float]] = [[] for _ in runs]
    for _ in range(repeats):
        for index, run in enumerate(runs):
            start = time.perf_counter()
            run()
            times[index].append(time.perf_counter() - start)
    return [1e3 * statistics.median(t) for t in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="cpu")
    parser.add_argument("--sizes", default="256x256,600x800")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load_config(args.config)
    plain = build_network(cfg.net).eval()
    wrapped = SurfaceAwareNet(plain).eval()
    print(
        f"config {args.config}, {args.threads} thread(s) [{instruction_sets()}], median of {args.repeats} frames, "
        "interleaved (ms)"
    )
    print(f"{'size':>10} {'plain':>9} {'surface':>9} {'extra':>8} {'photometric':>12}")
    for size in args.sizes.split(","):
        height, width = (int(v) for v in size.split("x"))
        gen = torch.Generator().manual_seed(0)
        target, captured = torch.rand(2, 1, 3, height, width, generator=gen)
        rho = 0.1 + 0.9 * torch.rand(1, 3, height, width, generator=gen)
        ambient = 0.05 * rho
        with torch.inference_mode():
            t_plain, t_surface, t_photo = interleaved_median_ms(
                [
                    lambda: plain(target, captured),
                    lambda: wrapped(target, captured, rho, ambient),
                    lambda: photometric_compensation(target, rho, ambient),
                ],
                args.warmup,
                args.repeats,
            )
        print(f"{size:>10} {t_plain:9.1f} {t_surface:9.1f} {t_surface - t_plain:8.1f} {t_photo:12.2f}")


if __name__ == "__main__":
    main()
