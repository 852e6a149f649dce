"""Where the display guard's time goes, per stage, on the CPU or a GPU.

The shipped ``doe+net`` method is a network behind its display guard
(:class:`edofproj.methods.guard.GuardedNetwork`): per frame the network (whose linear filter
output the guard keeps) and the decision, scored on tiles of the SSIM map
(:func:`~edofproj.methods.guard.tiled_guard_choice`) or, exactly, on the whole frame: per guard
depth one flat-screen projection and one SSIM of the network's and the filter's inputs (batched).
This times each of those stages alone at one frame size (medians; CUDA
events on a GPU, the wall clock on the CPU), the SSIM's separable Gaussian filter in both memory
layouts, and the whole guarded module against its bare network.

    PYTHONPATH=src python benchmarks/guard_cost.py [--run builtin:cpu-doe-unet] [--size 600x800] [--device cuda]

With ``--agreement`` it measures instead how often the tiled decision that ships differs from the
exact one (the whole frame's SSIM map) on the run's test images scaled to cover ``--size``, at the
scored depths (``--depths-mm``, flat screens; ``captured`` the uncompensated display), and the SSIM
each disagreement costs at the screen's depth (what is shown against what the exact rule shows).
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np
import torch

from edofproj.data.test_images import build_test_images
from edofproj.data.validation import validation_images
from edofproj.evaluation.timing import measure_cuda_ms, measure_ms
from edofproj.imaging.projection import project
from edofproj.machine import instruction_sets
from edofproj.methods.builder import build_method
from edofproj.methods.guard import GuardedNetwork, guard_choice, guard_tiles, tiled_guard_choice
from edofproj.metrics import SSIMReference, _filter_valid, gaussian_window, ssim
from edofproj.runs.directory import load_run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="builtin:cpu-doe-unet", help="a run whose doe+net is guarded")
    parser.add_argument("--size", default="600x800", help="HEIGHTxWIDTH (600x800)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (cpu)")
    parser.add_argument("--repeats", type=int, default=20, help="timed calls per stage (20)")
    parser.add_argument("--threads", type=int, default=None, help="PyTorch CPU threads")
    parser.add_argument("--agreement", action="store_true", help="tiled against exact decision on the test images")
    parser.add_argument("--validation", action="store_true", help="with --agreement: the validation set's images")
    parser.add_argument(
        "--depths-mm", default="300:800:50", help="scored depths, START:STOP:STEP or a list A,B,.. mm (300:800:50)"
    )
    parser.add_argument(
        "--work-fractions",
        default="",
        help="with --agreement: also these tiled budgets, e.g. 0.15,0.3 (the shipped one first)",
    )
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    height, width = (int(v) for v in args.size.lower().split("x"))
    if args.agreement:
        extra = [float(v) for v in args.work_fractions.split(",") if v]
        return agreement(args.run, height, width, args.depths_mm, extra, args.validation)
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
    tiles = guarded.tiles_for(height, width)
    psfs = guarded.psfs.contiguous()
    stages = [
        ("guarded module (what ships)", lambda: guarded(target, captured)),
        ("bare network", lambda: guarded.net(target, captured)),
        (
            f"tiled decision, {len(tiles)} tiles of {guarded.tile_px} px (ships)",
            lambda: tiled_guard_choice(target, network_input, filter_input, psfs, tiles, guarded.tile_px),
        ),
        ("exact decision, whole frame", lambda: guard_choice(target, network_input, filter_input, screens)),
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


def agreement(
    run_dir: str, height: int, width: int, depths_mm: str, extra_fractions: list[float], validation: bool = False
) -> int:
    """Print, per test image and depth, the exact and the tiled margins (the shipped budget, then each of
    ``extra_fractions``) and the SSIM a disagreement of the shipped one costs at the screen's depth; then,
    per budget, the disagreement rate and the worst loss."""
    method = build_method(run_dir)
    guarded = method.module
    assert isinstance(guarded, GuardedNetwork)
    if ":" in depths_mm:
        start, stop, step = (float(v) for v in depths_mm.split(":"))
        depths_m = np.arange(start, stop + step / 2, step) * 1e-3
    else:
        depths_m = np.array([float(v) for v in depths_mm.split(",")]) * 1e-3
    cfg = load_run(run_dir).cfg
    if validation:
        images = validation_images((height, width), cfg.evaluation.image_scaling)
    else:
        images = build_test_images(cfg.data, (height, width))
    exact_screens = [lambda v, psf=psf: project(v, psf[None]) for psf in guarded.psfs]
    psfs = guarded.psfs.contiguous()
    budgets = [guarded.work_fraction, *extra_fractions]
    tilings = [guard_tiles(height, width, psfs.shape[-1], guarded.tile_px, f) for f in budgets]
    print(
        f"tiled against exact display guard of {run_dir} at {height}x{width}, tiles of {guarded.tile_px} px, "
        f"{len(images)} {'validation' if validation else 'test'} images x {len(depths_m)} depths [{instruction_sets()}]"
    )
    for fraction, tiles in zip(budgets, tilings):
        print(f"  work fraction {fraction:g}: {len(tiles)} tiles")
    heads = " ".join(f"{'tiled ' + format(f, 'g'):>11}" for f in budgets)
    print(f"  {'image':<16} {'mm':>5} {'exact':>11} {heads} {'SSIM loss':>10}")
    cases = 0
    disagreements = [0] * len(budgets)
    worst = [0.0] * len(budgets)
    with torch.inference_mode():
        for name, image in images:
            target = image[None]
            for depth_m in depths_m:
                psf = method.design.psf([depth_m])
                captured = project(target, psf)
                network_input, filter_input = guarded._network_and_filter(target, captured)
                exact, exact_margin = guard_choice(target, network_input, filter_input, exact_screens)
                exact_ssim = float(ssim(project(exact, psf), target))
                margins = []
                for k, tiles in enumerate(tilings):
                    tiled, margin = tiled_guard_choice(
                        target, network_input, filter_input, psfs, tiles, guarded.tile_px
                    )
                    margins.append(float(margin))
                    if bool(exact_margin < 0) != bool(margin < 0):
                        disagreements[k] += 1
                        worst[k] = max(worst[k], exact_ssim - float(ssim(project(tiled, psf), target)))
                        if k == 0:
                            loss = exact_ssim - float(ssim(project(tiled, psf), target))
                cases += 1
                shipped_agrees = bool(exact_margin < 0) == (margins[0] < 0)
                print(
                    f"  {name:<16} {depth_m * 1e3:5.0f} {float(exact_margin):11.5f} "
                    + " ".join(f"{m:11.5f}" for m in margins)
                    + (f" {0.0:10.5f}" if shipped_agrees else f" {loss:10.5f}"),
                    flush=True,
                )
    for fraction, count, loss in zip(budgets, disagreements, worst):
        print(
            f"work fraction {fraction:g}: {count} of {cases} decisions differ; worst SSIM loss at the screen's depth {loss:.5f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
