"""What cutting a DOE's depth-ensemble Wiener filter to fewer taps costs, on the held-out test images.

The blind linear filter ``doe+ensemble`` of a run's DOE (NSR ``--nsr``, the filter of the depth
ensemble over the scored range) kept to ``(2 r + 1)^2`` taps for each ``r`` of ``--radii``, applied to
centre crops of the built-in test photographs and projected at each depth of ``--depths-mm``:
the mean and worst-depth SSIM over those depths and the mean absolute CIELAB lightness error. The
multi-rate network's fixed linear path is this filter with ``r`` = its block size (4 px); the
evaluation's ``doe+ensemble`` keeps ``r = psf.window``.

    PYTHONPATH=src python benchmarks/ensemble_filter_taps.py RUN [--radii 4,8,16,33] [--depths-mm 300:800:100]
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import torch
from skimage.color import rgb2lab

from edofproj.data.photos import builtin_split, load_builtin_photo
from edofproj.imaging.projection import project
from edofproj.methods.compensators import EnsembleWienerCompensation, ensemble_depths_m
from edofproj.methods.designs import OpticalDesign
from edofproj.metrics import ssim
from edofproj.runs import load_run


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a trained run directory (or builtin:NAME)")
    parser.add_argument("--radii", default="4,8,16,33", help="comma-separated half-widths r (px)")
    parser.add_argument("--depths-mm", default="300:800:100", help="FIRST:LAST:STEP screen depths (mm)")
    parser.add_argument("--nsr", type=float, default=0.01, help="noise-to-signal ratio of the filter")
    parser.add_argument("--size", type=int, default=256, help="centre crop (px)")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    run = load_run(args.run)
    design = OpticalDesign("run", "doe", run.doe, run.cfg)
    first, last, step = (float(v) for v in args.depths_mm.split(":"))
    depths_m = np.arange(first, last + step / 2, step) * 1e-3
    crops = []
    for name in builtin_split(run.cfg.data.test_fraction)[1]:
        pixels = load_builtin_photo(name) / 255.0
        h, w = pixels.shape[:2]
        y, x = max((h - args.size) // 2, 0), max((w - args.size) // 2, 0)
        crops.append(pixels[y : y + args.size, x : x + args.size])
    target = torch.as_tensor(np.stack(crops), dtype=torch.float32).permute(0, 3, 1, 2)
    lightness = rgb2lab(target.permute(0, 2, 3, 1).numpy())[..., 0]
    psfs = design.psf(depths_m)
    ensemble = design.psf(ensemble_depths_m(run.cfg))
    print(f"{len(crops)} test images, depths {', '.join(f'{z * 1e3:.0f}' for z in depths_m)} mm, NSR {args.nsr:g}")
    print(f"{'r (px)':>7s} {'taps':>7s} {'mean SSIM':>10s} {'worst SSIM':>11s} {'|dL*|':>7s}")
    for radius in (int(v) for v in args.radii.split(",")):
        x = EnsembleWienerCompensation(ensemble, args.nsr, radius)(target, target, None)
        scores, errors = [], []
        for psf in psfs:
            shown = project(x, psf.unsqueeze(0))
            scores.append(float(ssim(shown, target).mean()))
            errors.append(
                float(np.abs(rgb2lab(shown.clamp(0, 1).permute(0, 2, 3, 1).numpy())[..., 0] - lightness).mean())
            )
        print(
            f"{radius:7d} {(2 * radius + 1) ** 2:7d} {np.mean(scores):10.4f} {min(scores):11.4f} {np.mean(errors):7.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
