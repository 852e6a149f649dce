"""Where the display guard's time goes, per stage, on the CPU or a GPU.

The shipped ``doe+net`` method is a network behind its display guard
(:class:`edofproj.methods.guard.GuardedNetwork`): per frame the network, its linear filter once
more, and per guard depth one flat-screen projection and one SSIM of the network's and the
filter's inputs (batched). This times each of those stages alone at one frame size (medians; CUDA
events on a GPU, the wall clock on the CPU), the SSIM's separable Gaussian filter in both memory
layouts, and the whole guarded module against its bare network.

    PYTHONPATH=src python benchmarks/guard_cost.py [--run builtin:cpu-doe-net] [--size 600x800] [--device cuda]
"""

from __future__ import annotations

import argparse
import statistics

import torch

from edofproj.evaluation.timing import measure_cuda_ms, measure_ms
from edofproj.machine import instruction_sets
from edofproj.methods.builder import build_method
from edofproj.methods.guard import GuardedNetwork
from edofproj.metrics import SSIMReference, _filter_valid, gaussian_window


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="builtin:cpu-doe-net", help="a run whose doe+net is guarded")
    parser.add_argument("--size", default="600x800", help="HEIGHTxWIDTH (600x800)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (cpu)")
    parser.add_argument("--repeats", type=int, default=20, help="timed calls per stage (20)")
    parser.add_argument("--threads", type=int, default=None, help="PyTorch CPU threads")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    height, width = (int(v) for v in args.size.lower().split("x"))
    guarded = build_method(args.run).module
    if not isinstance(guarded, GuardedNetwork):
        parser.error(f"--run {args.run}: its doe+net is not behind a display guard")
    guarded = guarded.eval().to(device)
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(1, 3, height, width, generator=generator).to(device)
    captured = torch.rand(1, 3, height, width, generator=generator).to(device)

    def median_ms(frame) -> float:
        with torch.inference_mode():
            if device.type == "cuda":
                return statistics.median(measure_cuda_ms(frame, repeats=args.repeats, warmup=3))
            return statistics.median(measure_ms(frame, repeats=args.repeats, warmup=2))

    with torch.inference_mode():
        network_input = guarded.net(target, captured)
        filter_input = guarded.linear_base(target)
        both = torch.cat([network_input, filter_input])
        screens = guarded._screens_for(target)
        reference = SSIMReference(target)
        projected = [screen(both) for screen in screens]
        window = gaussian_window(dtype=target.dtype, device=device)
    stacked = torch.cat([both, both * both, both * target], dim=1)  # (2, 9, H, W): what one SSIM filters
    channels_last = stacked.contiguous(memory_format=torch.channels_last)
    stages = [
        ("guarded module (what ships)", lambda: guarded(target, captured)),
        ("bare network", lambda: guarded.net(target, captured)),
        ("linear filter E(I)", lambda: guarded.linear_base(target)),
        (f"{len(screens)} projections of 2 images", lambda: [screen(both) for screen in screens]),
        ("SSIM reference (target statistics)", lambda: SSIMReference(target)),
        (f"{len(screens)} SSIMs of 2 images", lambda: [reference.ssim(p) for p in projected]),
        # the SSIM's filter in each layout (its input already laid out so: no copy timed)
        (
            "Gaussian filter, 9 channels x 2, channels_last",
            lambda: _filter_valid(channels_last, window, torch.channels_last),
        ),
        (
            "Gaussian filter, 9 channels x 2, contiguous",
            lambda: _filter_valid(stacked, window, torch.contiguous_format),
        ),
    ]
    where = f"{device}" + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else "")
    print(
        f"display guard of {args.run} at {height}x{width} on {where}, {torch.get_num_threads()} CPU thread(s) "
        f"[{instruction_sets()}], median of {args.repeats} ({'CUDA events' if device.type == 'cuda' else 'wall clock'})"
    )
    print(f"  {'stage':<50} {'ms':>8}")
    for name, frame in stages:
        print(f"  {name:<50} {median_ms(frame):8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
