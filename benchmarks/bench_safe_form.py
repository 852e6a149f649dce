"""What the multi-rate network's safe form costs per frame: the network with and without it.

The safe form (``net.correction_bound > 0``, ``net.correction_highpass_px``) bounds and high-passes
the non-linear part around the network's own linear path. This script times the multi-rate network
at two widths, unbounded and in the safe form (bound 0.2, high-pass 8 px), and in the safe form on 2x2 blocks, *interleaved*
(:func:`bench_realtime.interleaved_ms`), with the inputs in the contiguous or the channels-last
layout, and prints each median and the median per-round ratio to the unbounded 8-16 network (the
``realtime`` preset's widths). The weights are randomized slightly: the cost does not depend on them.

    .venv/bin/python benchmarks/bench_safe_form.py [--size 600x800] [--rounds 40] [--threads 2]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from edofproj.compensation.multirate import MultirateCompensationNet
from edofproj.evaluation import timing
from edofproj.machine import instruction_sets

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_realtime import interleaved_ms, print_ratio_rows  # noqa: E402

#: name: (widths, block size, correction bound)
VARIANTS = {
    "8-16": ([8, 16], 4, 0.0),
    "8-16 safe": ([8, 16], 4, 0.2),
    "32-16": ([32, 16], 4, 0.0),
    "32-16 safe": ([32, 16], 4, 0.2),
    "8-8 safe, 2x2 blocks": ([8, 8], 2, 0.2),
    "16-16 safe, 2x2 blocks": ([16, 16], 2, 0.2),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="600x800", help="frame size HxW")
    parser.add_argument("--rounds", type=int, default=40, help="interleaved rounds (frames per network)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    (height, width), *_ = timing.parse_sizes(args.size)
    generator = torch.Generator().manual_seed(0)
    print(
        f"bench_safe_form: {height}x{width}, torch {torch.__version__}, {args.threads} thread(s), "
        f"[{instruction_sets()}], median of {args.rounds} interleaved rounds (ms per 3-channel frame)"
    )
    print("| network | inputs | median ms | median ratio to 8-16 |")
    print("| --- | --- | ---: | ---: |")
    for layout in (torch.contiguous_format, torch.channels_last):
        target = torch.rand(1, 3, height, width, generator=generator).contiguous(memory_format=layout)
        captured = (0.8 * target + 0.1).contiguous(memory_format=layout)
        frames = {}
        for name, (widths, block, bound) in VARIANTS.items():
            net = MultirateCompensationNet(widths, block=block, correction_bound=bound, correction_highpass_px=8.0)
            with torch.no_grad():
                for p in net.parameters():
                    p.add_(0.01 * torch.randn(p.shape, generator=generator))
            net = net.eval().to(memory_format=layout)  # type: ignore[call-overload]

            def frame(net=net):
                with torch.inference_mode():
                    net(target, captured)

            frames[name] = frame
        times = interleaved_ms(frames, args.rounds, warmup=3)
        print_ratio_rows(times, "8-16", "channels-last" if layout == torch.channels_last else "contiguous")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
