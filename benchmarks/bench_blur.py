"""The safe forms' Gaussian blur: blur matrices against the separable convolutions, per call.

``edofproj.compensation.linear_base.gaussian_blur`` multiplies by two blur matrices up to
``MATRIX_BLUR_MAX_PX`` and convolves beyond it. This script times both forms
(``blur_by_matrices``, ``blur_by_convolutions``), interleaved, on the
shapes the networks blur: the multi-rate network's block means (one colour and three, 150x200, sigma
2 blocks), the ``cpu`` U-Net's correction at 600x800 (sigma 8 px) and a training batch of it
(4 x 3 x 128 x 128), and prints the median milliseconds of each and their largest difference.

    .venv/bin/python benchmarks/bench_blur.py [--rounds 30] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import torch

from edofproj.compensation.linear_base import blur_by_convolutions, blur_by_matrices
from edofproj.machine import instruction_sets

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_realtime import interleaved_ms  # noqa: E402

#: (what, shape, sigma in samples)
CASES = [
    ("multi-rate block means, one colour", (1, 1, 150, 200), 2.0),
    ("multi-rate block means, three colours", (1, 3, 150, 200), 2.0),
    ("cpu U-Net correction, 600x800", (1, 3, 600, 800), 8.0),
    ("cpu U-Net correction, training batch", (4, 3, 128, 128), 8.0),
]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=30, help="interleaved rounds")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    generator = torch.Generator().manual_seed(0)
    print(f"bench_blur: torch {torch.__version__}, {args.threads} thread(s), [{instruction_sets()}]")
    print("| shape | sigma | matrices ms | convolutions ms | largest difference |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for what, shape, sigma in CASES:
        image = torch.rand(shape, generator=generator)
        with torch.inference_mode():
            difference = float((blur_by_matrices(image, sigma) - blur_by_convolutions(image, sigma)).abs().max())
            times = interleaved_ms(
                {
                    "matrices": lambda: blur_by_matrices(image, sigma),
                    "convolutions": lambda: blur_by_convolutions(image, sigma),
                },
                args.rounds,
                warmup=3,
            )
        print(
            f"| {what} {'x'.join(map(str, shape))} | {sigma:g} | {statistics.median(times['matrices']):.2f} | "
            f"{statistics.median(times['convolutions']):.2f} | {difference:.1e} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
