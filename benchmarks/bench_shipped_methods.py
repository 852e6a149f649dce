"""What each shipped method costs per frame, as ``compensate`` and ``live`` run it: interleaved timing.

The methods are built exactly as ``edofproj evaluate`` scores them and ``compensate`` runs them
(:func:`edofproj.methods.builder.build_method`): for the reference model ``builtin:cpu-doe-net``,
``doe+net`` (the network behind its display guard, one module), the same network without its
guard, and its blind linear filter ``doe+ensemble``; beside them FFT Wiener with a cached filter
(PyTorch, 33x33 PSF, as ``edofproj bench``) and the real-time network (the ``realtime`` preset's
multi-rate network, untrained: the cost does not depend on the weights; it has no linear base
filter, so no guard). Frames are channels-last, as ``live`` feeds them.

The machine's speed drifts, so in every round each method compensates one frame, in a rotating
order; the script prints per method the median milliseconds and the median per-round ratio to
FFT Wiener, and the CPU's instruction sets.

    .venv/bin/python benchmarks/bench_shipped_methods.py [--sizes 256x256,600x800] [--rounds 10] [--threads 2]
"""

from __future__ import annotations

import argparse
import sys

import torch

from edofproj.compensation.registry import build_network
from edofproj.config import load_config
from edofproj.evaluation import timing
from edofproj.evaluation.timing import disk_psf
from edofproj.machine import instruction_sets
from edofproj.methods.builder import build_method

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from bench_realtime import interleaved_ms, print_ratio_rows  # noqa: E402  (the same interleaving as the real-time benchmark)


def frame_function(compensate, height: int, width: int):
    """One compensated channels-last frame per call, in inference mode."""
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(1, 3, height, width, generator=generator).contiguous(memory_format=torch.channels_last)
    captured = (0.8 * target + 0.1).contiguous(memory_format=torch.channels_last)

    def frame():
        with torch.inference_mode():
            compensate(target, captured)

    return frame


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="builtin:cpu-doe-net", help="the trained run (default: the reference model)")
    parser.add_argument("--sizes", default="256x256,600x800", help="frame sizes HxW, comma-separated")
    parser.add_argument("--rounds", type=int, default=10, help="interleaved rounds (frames per method)")
    parser.add_argument("--warmup", type=int, default=1, help="untimed rounds first")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    shipped = build_method(args.run, "doe+net")
    ensemble = build_method(args.run, "doe+ensemble")
    guarded, bare = shipped.module, shipped.network
    assert guarded is not None and bare is not None
    for module in (guarded, bare):
        module.eval().to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    realtime = build_network(load_config("realtime").net).eval().to(memory_format=torch.channels_last)
    wiener = timing.wiener_torch_case(disk_psf(33), 1e-3, "cpu")

    print(
        f"bench_shipped_methods: {args.run}, torch {torch.__version__}, {args.threads} thread(s), "
        f"[{instruction_sets()}], median of {args.rounds} interleaved rounds (ms per 3-channel frame)"
    )
    print("| method | size | median ms | median ratio to FFT Wiener |")
    print("| --- | --- | ---: | ---: |")
    for size in timing.parse_sizes(args.sizes):
        height, width = size
        frames = {
            "FFT Wiener (PyTorch, cached filter)": wiener.build(height, width),
            "doe+ensemble (blind linear filter)": frame_function(
                lambda t, c: ensemble.compensate(t, c, None), height, width
            ),
            "doe+net as shipped (network + guard)": frame_function(guarded, height, width),
            "doe+net network alone (no guard)": frame_function(bare, height, width),
            "real-time network (multirate, no guard)": frame_function(realtime, height, width),
        }
        times = interleaved_ms(frames, args.rounds, args.warmup)
        print_ratio_rows(times, "FFT Wiener (PyTorch, cached filter)", f"{height}x{width}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
