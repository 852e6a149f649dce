"""Milliseconds per compensated frame of the U-Net width presets (CPU), and parameter counts.

For each preset of ``edofproj.compensation.unet.UNET_WIDTH_PRESETS`` and each frame size,
prints the median time of one 3-channel frame (batch 1) with

* PyTorch, ``channels_last`` memory format, ``torch.inference_mode``;
* ONNX Runtime (CPU provider), from the legacy exporter (opset 17, dynamic height/width);

and, as the reference the fast preset should beat, SciPy-FFT Wiener deconvolution with a
cached filter (``edofproj.compensation.wiener.WienerCompensator``, 33×33 PSF). Timings are
the median over ``--repeats`` frames after ``--warmup`` frames; the weights do not matter.

    .venv/bin/python benchmarks/bench_unet.py [--presets fast,default] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from edofproj.compensation.unet import UNET_WIDTH_PRESETS, CompensationUNet
from edofproj.machine import instruction_sets

SIZES = ((256, 256), (600, 800), (768, 1024))


def median_ms(run, warmup: int, repeats: int) -> float:
    for _ in range(warmup):
        run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def frame(height: int, width: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, height, width, generator=gen), torch.rand(1, 3, height, width, generator=gen)


def time_pytorch(net: CompensationUNet, height: int, width: int, warmup: int, repeats: int) -> float:
    net = net.to(memory_format=torch.channels_last).eval()
    target, captured = (t.contiguous(memory_format=torch.channels_last) for t in frame(height, width))
    with torch.inference_mode():
        return median_ms(lambda: net(target, captured), warmup, repeats)


def onnx_session(net: CompensationUNet, folder: Path, threads: int):
    import onnxruntime

    path = folder / "unet.onnx"
    axes = {0: "batch", 2: "height", 3: "width"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net.eval().to(memory_format=torch.contiguous_format),
            frame(64, 64),
            str(path),
            opset_version=17,
            dynamo=False,
            input_names=["target", "captured"],
            output_names=["projector_input"],
            dynamic_axes={"target": axes, "captured": axes, "projector_input": axes},
        )
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def time_onnx(session, height: int, width: int, warmup: int, repeats: int) -> float:
    target, captured = frame(height, width)
    feed = {"target": target.numpy(), "captured": captured.numpy()}
    return median_ms(lambda: session.run(None, feed), warmup, repeats)


def time_wiener(height: int, width: int, threads: int, warmup: int, repeats: int) -> float:
    from edofproj.compensation.wiener import WienerCompensator

    radius = 16
    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    disk = (x**2 + y**2 <= radius**2).astype(np.float64)
    psf = np.repeat((0.95 * disk / disk.sum())[None], 3, axis=0)
    wiener = WienerCompensator(psf, nsr=1e-2, workers=threads)
    image = frame(height, width)[0][0].numpy()
    return median_ms(lambda: wiener(image), warmup, repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--presets", default=",".join(UNET_WIDTH_PRESETS), help="comma-separated preset names (default: all)"
    )
    parser.add_argument(
        "--sizes", default=",".join(f"{h}x{w}" for h, w in SIZES), help="comma-separated HxW frame sizes"
    )
    parser.add_argument("--threads", type=int, default=2, help="intra-op threads (PyTorch, ONNX Runtime, SciPy FFT)")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-onnx", action="store_true", help="skip ONNX Runtime")
    parser.add_argument("--no-wiener", action="store_true", help="skip the Wiener reference")
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes.split(",")]
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    print(
        f"torch {torch.__version__}, {args.threads} thread(s) [{instruction_sets()}], median of {args.repeats} frames"
    )
    header = "| method | widths | parameters | " + " | ".join(f"{h}×{w} ms" for h, w in sizes) + " |"
    print(header)
    print("|" + " --- |" * (3 + len(sizes)))
    if not args.no_wiener:
        times = [time_wiener(h, w, args.threads, args.warmup, args.repeats) for h, w in sizes]
        print("| Wiener (SciPy FFT, cached filter) | - | - | " + " | ".join(f"{t:.1f}" for t in times) + " |")
    for name in presets:
        widths = UNET_WIDTH_PRESETS[name]
        net = CompensationUNet(widths)
        count = sum(p.numel() for p in net.parameters())
        times = [time_pytorch(net, h, w, args.warmup, args.repeats) for h, w in sizes]
        print(
            f"| U-Net {name}, PyTorch channels_last | {widths} | {count:,} | "
            + " | ".join(f"{t:.1f}" for t in times)
            + " |",
            flush=True,
        )
        if not args.no_onnx:
            with tempfile.TemporaryDirectory() as folder:
                session = onnx_session(CompensationUNet(widths), Path(folder), args.threads)
                times = [time_onnx(session, h, w, args.warmup, args.repeats) for h, w in sizes]
            print(
                f"| U-Net {name}, ONNX Runtime | {widths} | {count:,} | "
                + " | ".join(f"{t:.1f}" for t in times)
                + " |",
                flush=True,
            )


if __name__ == "__main__":
    main()
