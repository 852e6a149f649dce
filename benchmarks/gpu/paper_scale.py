"""Training at the paper's scale on a CUDA GPU: seconds per step and peak GPU memory, float32
against bf16 autocast for the network, and the effect of bf16 on the loss.

    python benchmarks/gpu/paper_scale.py --out /tmp/paper_scale [--steps 40] [--crop 1024]

Each precision trains the ``paper`` preset (2048 pupil samples, 11 wavelengths, the 7-scale U-Net,
batch 1) for ``--steps`` steps from the same seed on the same crops, through the real trainer
(``edofproj.training.trainer.train``). Two departures, both forced by what this machine holds:

* images: DIV2K is not shipped, and no built-in photograph has 1024 px on both sides, so the
  built-in *training* photographs are enlarged (bicubic) to cover ``--crop`` + 64 px and read as
  an image folder. The cost of a step does not depend on the content.
* loss: DISTS needs VGG16 weights that are not shipped: ``1 - MS-SSIM`` stands in (``--perceptual``).

Seconds per step: the median of the differences of the training log's ``seconds`` column after
``--skip`` warm-up steps (data loading included, as a user would see it). Peak memory: PyTorch's
``max_memory_allocated`` on the GPU. Loss effect: the mean loss of the last steps and the largest
relative difference of the per-step losses between the two precisions (same crops and depths).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from edofproj.config import load_config
from edofproj.data import builtin_split, fit_to_size, load_builtin_photo
from edofproj.imaging.image_io import to_unit_float, write_image
from edofproj.runs.log import read_log
from edofproj.training.trainer import train


def enlarged_training_photos(folder: Path, side_px: int, test_fraction: float) -> Path:
    """The built-in training photographs, each scaled to cover ``side_px`` (PNG, 8 bits)."""
    folder.mkdir(parents=True, exist_ok=True)
    train_names, _ = builtin_split(test_fraction)
    for name in train_names:
        pixels = load_builtin_photo(name)
        scale = side_px / min(pixels.shape[:2])
        if scale > 1:
            size = (int(np.ceil(pixels.shape[1] * scale)), int(np.ceil(pixels.shape[0] * scale)))
            pixels = cv2.resize(pixels, size, interpolation=cv2.INTER_CUBIC)
        pixels = fit_to_size(pixels, (max(side_px, pixels.shape[0]), max(side_px, pixels.shape[1])))
        image = torch.from_numpy(to_unit_float(np.ascontiguousarray(pixels)).transpose(2, 0, 1).copy())
        write_image(folder / f"{name}.png", image)
    return folder


def run(args) -> int:
    if args.device == "cuda" and not torch.cuda.is_available():
        print("paper_scale: needs a CUDA GPU (--device cpu for a smoke run)", file=sys.stderr)
        return 2
    out = Path(args.out)
    images = enlarged_training_photos(out / "images", args.crop + 64, 0.3)
    rows = []
    losses = {}
    for precision in args.precisions.split(","):
        overrides = [
            "data.source=folder",
            f"data.folder={images}",
            "data.test_fraction=0.3",
            f"data.crop={args.crop}",
            f"loss.perceptual={args.perceptual}",
            f"train.steps={args.steps}",
            f"train.checkpoint_every={args.steps}",
            f"train.device={args.device}",
            f"train.mixed_precision={precision}",
            f"psf.pupil_samples={args.pupil_samples}",
        ]
        cfg = load_config("paper", overrides)
        if args.device == "cuda":
            torch.cuda.reset_peak_memory_stats()
        result = train(cfg, out / f"run_{precision}", progress=False)
        log = read_log(out / f"run_{precision}" / "train_log.csv")
        seconds = [float(r["seconds"]) for r in log]
        steps = np.diff(seconds)[args.skip :]
        losses[precision] = np.array([float(r["loss"]) for r in log])
        rows.append(
            (
                precision,
                statistics.median(steps),
                float(np.percentile(steps, 90)),
                (result.peak_gpu_memory_bytes or 0) / 2**30,
                float(losses[precision][-10:].mean()),
            )
        )
    where = torch.cuda.get_device_name() if args.device == "cuda" else "the CPU"
    print(
        f"\npaper scale on {where} (torch {torch.__version__}): crop {args.crop}, "
        f"batch 1, {args.pupil_samples} pupil samples, 11 wavelengths, {args.steps} steps (first {args.skip} skipped)"
    )
    print("| precision | s/step (median) | s/step (p90) | peak GPU memory (GiB) | mean loss, last 10 steps |")
    print("|---|---:|---:|---:|---:|")
    for precision, median, p90, peak, loss in rows:
        print(f"| {precision} | {median:.4f} | {p90:.4f} | {peak:.2f} | {loss:.5f} |")
    if "none" in losses and "bf16" in losses:
        fp32, bf16 = losses["none"], losses["bf16"]
        speedup = rows[0][1] / rows[1][1] if rows[0][0] == "none" else rows[1][1] / rows[0][1]
        print(
            f"bf16 speed-up {speedup:.2f}x; per-step loss relative difference: median "
            f"{np.median(np.abs(bf16 - fp32) / fp32):.2e}, max {np.max(np.abs(bf16 - fp32) / fp32):.2e}"
        )
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="work directory (images and runs)")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--skip", type=int, default=5, help="warm-up steps left out of the timing")
    parser.add_argument("--crop", type=int, default=1024)
    parser.add_argument("--pupil-samples", type=int, default=2048)
    parser.add_argument("--perceptual", default="ms-ssim", help="loss.perceptual (DISTS needs weights)")
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda", help="cpu: a smoke run only")
    parser.add_argument("--precisions", default="none,bf16", help="train.mixed_precision values to compare")
    return run(parser.parse_args())


if __name__ == "__main__":
    sys.exit(main())
