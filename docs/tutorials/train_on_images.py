"""Tutorial 2: train a DOE and its compensation network on your own images.

    python docs/tutorials/train_on_images.py --out tutorial_out/train [--images MY_FOLDER] [--steps N] [--small]

Trains the ``cpu`` preset (a radial MLP DOE and a U-Net, end to end) on the PNG/JPEG images below
``--images`` for a short schedule, then looks at what the run directory holds: the saved
configuration, the fabricable DOE, the checkpoints, the training log and the figures. Without
``--images`` it first writes a folder of example photographs (the ones shipped with scikit-image
and matplotlib) to stand in for yours. The run is ``OUT/run``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from edofproj.config import dump_config, load_config
from edofproj.data import BUILTIN_PHOTOS, find_image_files, fit_to_size, folder_split, load_builtin_photo
from edofproj.fileio import write_text_atomic
from edofproj.imaging.image_io import to_unit_float, write_image
from edofproj.runs import load_run
from edofproj.runs.log import read_log
from edofproj.training.trainer import train

#: The smallest configuration that still trains every part (--small).
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
    "evaluation.image_size=[96,96]",  # the example images' size: they are scored, never enlarged
    "train.batch_size=2",
    "train.checkpoint_every=4",
    "train.psf_table_depths=4",
]


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder (the run goes to OUT/run)")
    parser.add_argument("--images", default=None, help="folder of PNG/JPEG training images (default: examples)")
    parser.add_argument(
        "--steps", type=int, default=None, help="steps of each training phase (default 600; 6 with --small)"
    )
    parser.add_argument("--threads", type=int, default=1, help="CPU threads for training (0: all)")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def write_example_images(folder: Path, count: int, size: int | None) -> None:
    """Stand-ins for your photographs: the built-in ones as PNG files (optionally shrunk)."""
    for name in list(BUILTIN_PHOTOS)[:count]:
        pixels = load_builtin_photo(name)
        if size is not None:
            pixels = fit_to_size(pixels, size)
        write_image(folder / f"{name}.png", to_unit_float(pixels).transpose(2, 0, 1))


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    # 1. The images. Any folder of PNG/JPEG files at least data.crop pixels on each side will do;
    #    a fixed share (data.test_fraction, split by file name) is held out for testing.
    images = Path(args.images) if args.images else out / "images"
    if args.images is None:
        images.mkdir(exist_ok=True)
        write_example_images(images, count=6 if args.small else len(BUILTIN_PHOTOS), size=96 if args.small else None)
    train_files, test_files = folder_split(images, test_fraction=0.3)
    print(
        f"{len(find_image_files(images))} images in {images}: {len(train_files)} for training, "
        f"{len(test_files)} held out ({', '.join(p.name for p in test_files)})"
    )

    # 2. The configuration: the cpu preset, reading the folder; a short schedule of its two phases
    #    (N steps of the DOE with a network, then N of a fresh network for the DOE found).
    steps = args.steps or (6 if args.small else 600)
    overrides = (SMALL if args.small else []) + [
        "data.source=folder",
        f"data.folder={images}",
        f"train.steps={steps}",
        f"train.refit_steps={steps}",
        f"train.refit_warmup_steps={min(300, steps // 2)}",  # the preset's 300, or half a shorter phase
        f"train.threads={args.threads}",
        "train.device=cpu",
    ]
    cfg = load_config("cpu", overrides)
    cfg.name = "my_images"

    # 3. Train (the same as: edofproj train --config cpu --set data.source=folder
    #    --set data.folder=IMAGES --steps N --set train.refit_steps=N --out OUT/run).
    run_dir = out / "run"
    result = train(cfg, run_dir, progress=False)
    print(f"trained {result.step} steps in {result.seconds:.0f} s; last loss {result.loss:.4f}")

    # 4. The run directory.
    for path in sorted(run_dir.rglob("*")):
        if path.is_file():
            print(f"  {path.relative_to(run_dir)}  ({path.stat().st_size / 1024:.0f} kB)")
    log = read_log(run_dir / "train_log.csv")
    losses = np.array([row["loss"] for row in log])
    tenth = max(1, len(losses) // 10)
    first, last = float(losses[:tenth].mean()), float(losses[-tenth:].mean())
    print(f"train_log.csv: {len(log)} rows; mean loss of the first tenth {first:.4f}, of the last tenth {last:.4f}")

    # 5. Load the run back as the other tools do (evaluate, compensate, export-doe).
    run = load_run(run_dir)
    print(f"load_run: step {run.step}, DOE: {run.doe.describe()}")
    print(f"network: {sum(p.numel() for p in run.net.parameters())} parameters")
    same = dump_config(run.cfg) == dump_config(cfg)
    print(f"config.yaml holds the full configuration: {'identical' if same else 'DIFFERENT'} to the one trained")

    summary = {
        "run_dir": str(run_dir),
        "images": len(find_image_files(images)),
        "train_images": len(train_files),
        "test_images": len(test_files),
        "steps": result.step,
        "loss_first_tenth": first,
        "loss_last_tenth": last,
        "figures": sorted(p.name for p in (run_dir / "figures").iterdir()),
        "doe_levels": run.doe.levels,
        "config_round_trip": same,
        "seconds": time.perf_counter() - start,
    }
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out}/summary.json ({summary['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
