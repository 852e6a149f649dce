"""Does ``compensate`` ship what the evaluation scores? SSIM of the display of its output, per image.

For validation images (default: the colour classes the display guard exists for, and two photographs),
at each depth: ``edofproj compensate RUN --images DIR --depth-mm Z --bits 16`` is run with the
edofproj of ``--compensate-src`` (default: this one; another checkout's ``src`` measures that one's
``compensate``), its 16-bit projector input is
projected with the run's DOE PSF at ``Z`` (:func:`edofproj.imaging.projection.project`), and its SSIM
against the target is printed beside the evaluation's own ``doe+net`` and ``doe+ensemble`` scores of the
same image and depth (the evaluation's method objects, built in this process).

    PYTHONPATH=src .venv/bin/python benchmarks/shipped_vs_scored.py [--run builtin:cpu-doe-net] [--depths-mm 300,550,800]
        [--compensate-src OTHER_CHECKOUT/src]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from edofproj.compensation.closed_loop import closed_loop, flat_screen
from edofproj.data.validation import validation_images
from edofproj.imaging.image_io import read_image, write_image
from edofproj.imaging.projection import project
from edofproj.methods.builder import build_method
from edofproj.metrics import ssim

DEFAULT_IMAGES = (
    "colour/grating,colour/flat_graphics,colour/Minduka_near_empty_blue,colour/saturated_leaves,"
    "colour/camera_dark,colour/textured_high_key,skimage/text,skimage/page,skimage/camera,skimage/colorwheel"
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="builtin:cpu-doe-net")
    parser.add_argument("--depths-mm", default="300,550,800")
    parser.add_argument("--images", default=DEFAULT_IMAGES, help="validation image names, comma-separated")
    parser.add_argument("--size", type=int, default=256, help="square crop (px)")
    parser.add_argument("--compensate-src", default=None, help="the src folder whose compensate is measured")
    args = parser.parse_args()
    torch.set_num_threads(2)
    names = [n for n in args.images.split(",") if n]
    images = validation_images((args.size, args.size), "crop", names=names)
    shipped_by = {name: build_method(args.run, name) for name in ("doe+net", "doe+ensemble")}
    source = args.compensate_src or os.environ.get("PYTHONPATH", "(installed)")
    env = dict(os.environ, PYTHONPATH=args.compensate_src) if args.compensate_src else None
    print(f"shipped_vs_scored: {args.run}, compensate from {source}, {args.size}x{args.size} crops")
    print("| image | depth mm | compensate (shipped) | evaluation doe+net | evaluation doe+ensemble |")
    print("| --- | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "in"
        folder.mkdir()
        files = {}
        for index, (name, image) in enumerate(images):
            files[name] = f"{index:02d}.png"
            write_image(folder / files[name], image, bits=16)
        for depth_mm in (float(z) for z in args.depths_mm.split(",")):
            out = Path(tmp) / f"out{depth_mm:g}"
            cli = "import sys; from edofproj.cli import main; sys.exit(main(sys.argv[1:]))"
            command = [sys.executable, "-c", cli, "compensate", args.run, "--images", str(folder)]
            command += ["--depth-mm", f"{depth_mm:g}", "--out", str(out), "--bits", "16"]
            subprocess.run(command, check=True, capture_output=True, env=env)
            psf = shipped_by["doe+net"].design.psf([depth_mm * 1e-3])
            forward = flat_screen(psf)
            for name, _ in images:
                target = read_image(folder / files[name])[None]
                shipped = read_image(out / files[name])[None]
                scores = [float(ssim(project(shipped, psf), target)[0])]
                with torch.inference_mode():
                    for method in shipped_by.values():
                        loop = closed_loop(target, forward, lambda t, c, m=method: m.compensate(t, c, psf))
                        scores.append(float(ssim(loop.projected, target)[0]))
                print(f"| {name} | {depth_mm:g} | " + " | ".join(f"{s:.4f}" for s in scores) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
