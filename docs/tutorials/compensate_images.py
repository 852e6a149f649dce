"""Tutorial 5: compensate images with a trained network from Python.

    python docs/tutorials/compensate_images.py --out tutorial_out/compensate [--run RUN] [--image IMG ...] [--small]

Loads a trained run (``--run``: the run of tutorial 2, ``runs/demo/doe_net`` from ``edofproj
demo``, ...; without it, a short run is trained first), and for each image and screen depth runs
the closed loop of the library -- simulate the uncompensated projection ``I*``, compute the
projector input ``x = net(I, I*)``, project it -- writes the projector image and the simulated
preview, and prints the SSIM of the projection with and without compensation, and of the bare
lens for comparison.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from edofproj.compensation.closed_loop import closed_loop, flat_screen
from edofproj.config import load_config
from edofproj.data import evaluation_images
from edofproj.fileio import atomic_path, write_text_atomic
from edofproj.imaging import project
from edofproj.imaging.image_io import read_image, write_image
from edofproj.methods.designs import OpticalDesign
from edofproj.metrics import ssim
from edofproj.runs import load_run
from edofproj.training.trainer import train

#: A tiny run, trained in seconds when --small is given without --run.
SMALL = [
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "psf.pupil_samples=384",
    "psf.window=15",
    "doe.mlp_frequencies=4",
    "doe.mlp_hidden=8",
    "net.widths=[4,8]",
    "net.linear_radius=15",
    "data.crop=32",
    "data.max_test_images=2",
    "train.steps=6",
    "train.refit_steps=6",
    "train.refit_warmup_steps=2",
    "train.batch_size=2",
    "train.checkpoint_every=6",
    "train.psf_table_depths=4",
    "evaluation.image_size=[64,64]",
]


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--run", default=None, help="a trained run directory (default: train a short one)")
    parser.add_argument(
        "--image", nargs="+", default=None, help="images to compensate (default: the run's test images)"
    )
    parser.add_argument("--depth-mm", type=float, nargs="+", default=None, help="screen depths (300 500 800)")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    start = time.perf_counter()

    # 1. A trained run. Without --run: the cpu preset on the built-in photographs, 400 steps
    #    (a couple of minutes on one core; the demo trains 1800), or a tiny run with --small.
    run_dir = Path(args.run) if args.run else out / "run"
    if args.run is None:
        overrides = SMALL if args.small else ["train.steps=400", "train.refit_steps=400", "train.threads=1"]
        train(load_config("cpu", overrides + ["train.device=cpu"]), run_dir, progress=False)
    run = load_run(run_dir)
    print(f"run {run_dir} at step {run.step}: {run.doe.describe()}")

    # 2. The images: files given with --image, or the run's held-out test images at the size of
    #    its evaluation (centre crops), (3, H, W) in [0, 1].
    if args.image:
        images = [(Path(p).stem, read_image(p)) for p in args.image]
    else:
        images = evaluation_images(run.cfg)
    depths_mm = args.depth_mm or ([300.0, 800.0] if args.small else [300.0, 500.0, 800.0])

    # 3. The PSFs of the run's DOE at those depths (the design's engine, simulated once), and for
    #    comparison those of the bare lens (no DOE, no compensation).
    design = OpticalDesign("run", "doe", run.doe, run.cfg)
    psfs = design.psf(np.array(depths_mm) * 1e-3)  # (n_depths, 3, K, K)
    lens_psfs = OpticalDesign("lens", "lens", None, run.cfg).psf(np.array(depths_mm) * 1e-3)

    # 4. The closed loop per image and depth: I* = A(I), x = net(I, I*), shown = A(x).
    rows = []
    panels = []
    for name, image in images:
        target = image.unsqueeze(0)
        for depth, psf, lens_psf in zip(depths_mm, psfs, lens_psfs):
            with torch.inference_mode():
                loop = closed_loop(target, flat_screen(psf[None]), run.net)
                lens_only = project(target, lens_psf[None])
            stem = f"{Path(name).stem}_{depth:.0f}mm"
            write_image(out / f"projector_{stem}.png", loop.emitted[0])  # what to send to the projector
            write_image(out / f"preview_{stem}.png", loop.projected[0])  # what the screen would show
            lens = float(ssim(lens_only, target))
            before = float(ssim(loop.captured, target))
            after = float(ssim(loop.projected, target))
            clipped = float((loop.compensated != loop.emitted).float().mean())
            rows.append(
                {
                    "image": name,
                    "depth_mm": depth,
                    "ssim_lens": lens,
                    "ssim_uncompensated": before,
                    "ssim_compensated": after,
                    "clipped_fraction": clipped,
                }
            )
            print(
                f"{name:<24} {depth:5.0f} mm  SSIM lens {lens:.4f}, DOE {before:.4f} -> compensated {after:.4f}  "
                f"({100 * clipped:.1f} % of the projector values clipped to [0, 1])"
            )
            if len(panels) < len(depths_mm):
                panels.append((depth, target[0], loop.captured[0], loop.emitted[0], loop.projected[0]))

    for depth in depths_mm:
        mine = [r for r in rows if r["depth_mm"] == depth]
        print(
            f"mean over {len(mine)} images at {depth:.0f} mm: SSIM lens {np.mean([r['ssim_lens'] for r in mine]):.4f}, "
            f"DOE {np.mean([r['ssim_uncompensated'] for r in mine]):.4f} -> compensated "
            f"{np.mean([r['ssim_compensated'] for r in mine]):.4f}"
        )
    plot_panels(panels, out / "compensation.png")
    summary = {"run": str(run_dir), "step": run.step, "rows": rows, "seconds": time.perf_counter() - start}
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out}/projector_*.png, preview_*.png, compensation.png ({summary['seconds']:.0f} s)")


def plot_panels(panels, path: Path) -> None:
    """One row per depth: target, uncompensated projection, projector input, compensated projection."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    titles = ("target I", "uncompensated A(I)", "projector input x", "compensated A(x)")
    fig, axes = plt.subplots(len(panels), 4, figsize=(8, 2.1 * len(panels)), squeeze=False, layout="constrained")
    for row, (depth, *images) in enumerate(panels):
        for col, image in enumerate(images):
            ax = axes[row, col]
            ax.imshow(image.permute(1, 2, 0).clamp(0, 1).numpy())
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(titles[col], fontsize=9)
            if col == 0:
                ax.set_ylabel(f"{depth:.0f} mm")
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
