"""ONNX Runtime against PyTorch on the exported networks, frame by frame in one process.

    .venv/bin/python benchmarks/bench_onnx.py                          # the three networks at 600x800, 2 threads
    .venv/bin/python benchmarks/bench_onnx.py --networks multirate --sizes 256x256,600x800 --repeats 20

Networks (``--networks``):

* ``multirate``: the untrained real-time network (widths 8,16, 4-px blocks, a 48-node radial
  Fourier filter), as ``edofproj bench --architecture multirate --widths 8,16 --space-to-depth 4
  --prefilter-bins 48`` builds it;
* ``cpu-unet``: the network of ``builtin:cpu-doe-unet`` (the ``cpu`` preset's U-Net with its linear
  base filter), without its display guard;
* ``cpu-guarded``: the same network behind its display guard, what ``edofproj bench --run
  builtin:cpu-doe-unet`` and ``edofproj export builtin:cpu-doe-unet`` take.

Each network is exported as ``edofproj export`` writes it (for the frame size; verified against
PyTorch), then PyTorch (inference mode, channels-last weights, as ``edofproj bench`` runs it) and
ONNX Runtime (``--threads`` intra-op threads) compute alternate frames, the first of each pair
alternating. The ratio ONNX / PyTorch of each pair is robust to the load of a shared machine, which
changes slowly next to a frame; its median and range over ``--repeats`` pairs are printed with the
median milliseconds of each, the ratio of the median process CPU times (with ``--threads 1`` the
figure least moved by other processes: a one-thread process is charged only while it runs; with
more threads it also counts the threads' waiting), the load average after the pairs, the export's
largest difference from PyTorch, the file's size, and the CPU's instruction sets.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import torch

from edofproj.compensation.export import export_network
from edofproj.compensation.registry import network_from_widths
from edofproj.evaluation import timing
from edofproj.machine import instruction_sets

NETWORKS = ("multirate", "cpu-unet", "cpu-guarded")


def build(name: str) -> torch.nn.Module:
    if name == "multirate":
        return network_from_widths("8,16", 4, 48, "multirate")
    from edofproj.methods.builder import build_method

    shipped = build_method("builtin:cpu-doe-unet")
    network = shipped.module if name == "cpu-guarded" else shipped.network
    assert network is not None
    return network


def interleaved_ms(first, second, repeats: int, warmup: int) -> list[tuple[list[float], list[float]]]:
    """``[(wall ms, process CPU ms), ...]`` of ``repeats`` calls of each frame function (first, second),
    called in alternating pairs."""
    for _ in range(warmup):
        first()
        second()
    times: list[tuple[list[float], list[float]]] = [([], []), ([], [])]
    for index in range(repeats):
        for which in (0, 1) if index % 2 == 0 else (1, 0):
            wall, cpu = time.perf_counter(), time.process_time()
            (first, second)[which]()
            times[which][1].append((time.process_time() - cpu) * 1e3)
            times[which][0].append((time.perf_counter() - wall) * 1e3)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--networks", default=",".join(NETWORKS), help=f"comma-separated subset of {NETWORKS}")
    parser.add_argument("--sizes", default="600x800", help="frame sizes HxW, comma-separated")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (PyTorch and ONNX Runtime)")
    parser.add_argument("--repeats", type=int, default=10, help="timed pairs of frames per network and size")
    parser.add_argument("--warmup", type=int, default=2, help="untimed pairs first")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    sizes = timing.parse_sizes(args.sizes)
    one, five, _ = os.getloadavg()
    print(
        f"bench_onnx: torch {torch.__version__}, onnxruntime {__import__('onnxruntime').__version__}, "
        f"{args.threads} thread(s) of {os.cpu_count()} [{instruction_sets()}]; {args.repeats} interleaved pairs "
        f"of frames; load average {one:.1f}, {five:.1f} (1, 5 min)"
    )
    print(
        "| network | size | ONNX / PyTorch, wall: median (range) | PyTorch ms | ONNX Runtime ms "
        "| ONNX / PyTorch, CPU time | load | max diff | file MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="bench-onnx-") as folder:
        for name in args.networks.split(","):
            net = build(name.strip()).eval()
            for height, width in sizes:
                path = Path(folder) / f"{name}-{height}x{width}.onnx"
                difference = export_network(net, path, "onnx", height, width)
                torch_frame = timing.network_torch_case(net, name).build(height, width)
                onnx_frame = timing.network_onnx_case(str(path), name, "cpu", args.threads).build(height, width)
                (onnx_ms, onnx_cpu), (torch_ms, torch_cpu) = interleaved_ms(
                    onnx_frame, torch_frame, args.repeats, args.warmup
                )
                ratios = sorted(o / t for o, t in zip(onnx_ms, torch_ms))
                cpu_ratio = statistics.median(onnx_cpu) / statistics.median(torch_cpu)
                print(
                    f"| {name} | {height}x{width} | {statistics.median(ratios):.2f} ({ratios[0]:.2f}-{ratios[-1]:.2f}) "
                    f"| {statistics.median(torch_ms):.1f} | {statistics.median(onnx_ms):.1f} | {cpu_ratio:.2f} "
                    f"| {os.getloadavg()[0]:.1f} | {difference:.1e} | {path.stat().st_size / 1e6:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
