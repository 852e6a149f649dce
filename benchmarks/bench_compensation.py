"""Benchmark compensation time per 3-channel frame next to the paper's Table 1 (V100 GPU).

Times, on the CPU (and CUDA when available):

* non-blind Wiener (SciPy FFT with cached filter; PyTorch with cached filter);
* the compensation U-Net of each width preset (PyTorch channels_last + inference_mode, and
  ONNX Runtime), untrained (the cost does not depend on the weights);
* the OnlineProDeb re-implementation (default preset) at 256×256 only, as in the paper;
* box-constrained least squares (``lens+cls``, 100 FISTA iterations) at 256×256 only.

    python benchmarks/bench_compensation.py                       # all presets, 5 repeats
    python benchmarks/bench_compensation.py --presets fast --threads 2 --csv timings.csv
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

from edofproj.compensation.export import export_network
from edofproj.compensation.onlineprodeb import OnlineProDebNet
from edofproj.compensation.unet import CompensationUNet, width_preset
from edofproj.evaluation import timing
from edofproj.evaluation.timing import disk_psf
from edofproj.fileio import write_text_atomic
from edofproj.machine import instruction_sets

PAPER_SIZES = [(256, 256), (600, 800), (768, 1024)]
PAPER_TABLE_1 = """Paper, Table 1 (V100 GPU, ms per 3-channel frame):
| resolution | non-blind Wiener | OnlineProDeb | proposed |
|---|---|---|---|
| 256x256 | 1.5 | 90 | 3.6 |
| 600x800 | 24 | n/a | 4.5 |
| 768x1024 | 37 | n/a | 5.6 |"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--presets", default="fast,default,paper", help="U-Net width presets to time")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (default: PyTorch's default)")
    parser.add_argument("--window", type=int, default=33, help="PSF window for Wiener and CLS")
    parser.add_argument("--csv", default=None, help="write all timings as CSV")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    psf = disk_psf(args.window)

    def progress(t: timing.Timing) -> None:
        print(f"  {t.method}/{t.backend}/{t.device} {t.height}x{t.width}: {t.median_ms:.1f} ms", file=sys.stderr)

    results: list[timing.Timing] = []
    with tempfile.TemporaryDirectory() as tmp:
        for device in devices:
            full = []
            if device == "cpu":
                full.append(timing.wiener_scipy_case(psf, workers=args.threads))
            full.append(timing.wiener_torch_case(psf, device=device))
            for preset in [p.strip() for p in args.presets.split(",") if p.strip()]:
                net = CompensationUNet(width_preset(preset))
                full.append(timing.network_torch_case(net, f"unet-{preset}", device))
                if timing.onnx_available(device):
                    path = Path(tmp) / f"unet-{preset}.onnx"
                    if not path.exists():
                        export_network(net, path, "onnx", 256, 256)
                    full.append(timing.network_onnx_case(str(path), f"unet-{preset}", device, args.threads))
            results += timing.time_cases(full, PAPER_SIZES, args.repeats, args.warmup, progress)
            small = [
                timing.network_torch_case(OnlineProDebNet.from_preset("default"), "onlineprodeb", device),
                timing.cls_torch_case(psf, 100, device),
            ]
            results += timing.time_cases(small, PAPER_SIZES[:1], args.repeats, args.warmup, progress)

    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} thread(s) [{instruction_sets()}], "
        f"PSF window {args.window}, "
        f"median of {args.repeats} frames (ms per 3-channel frame)"
    )
    print(timing.format_table(results))
    print()
    print(PAPER_TABLE_1)
    if args.csv:
        write_text_atomic(args.csv, timing.timings_csv(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
