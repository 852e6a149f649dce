"""Where a compensation's colour error is: CIEDE2000 on edges and on flat areas, lightness against chroma.

For each run, method, held-out test image and screen depth, the method is built as ``evaluate`` and
``compensate`` build it (:func:`edofproj.methods.builder.build_method`), compensates the image, and
its clamped projector input is projected through the run's design at that depth:

    x = method(I, I*),     shown = project(clamp(x, 0, 1), p_z)

Printed per case: the mean CIEDE2000 of ``shown`` against ``I`` over the whole image, over its
*edges* (the top 20 % of the target's Sobel gradient magnitude) and over its *flat* areas (the
lowest 40 %), and the mean absolute CIELAB lightness error |ΔL*| and chroma error |Δ(a*, b*)|. A
network whose error grows on flat areas and in lightness misses low-contrast texture; one whose error
grows on edges and in chroma makes colour fringes.

    PYTHONPATH=src python benchmarks/colour_error_regions.py RUN [RUN ...] [--methods doe+net,doe+ensemble]
        [--images chelsea,coffee] [--depths-mm 500,800] [--size 256]

The images are centre crops of the built-in test photographs (``data.source: builtin``).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import torch
from scipy import ndimage
from skimage.color import deltaE_ciede2000, rgb2lab

from edofproj.data.photos import load_builtin_photo
from edofproj.imaging.projection import project
from edofproj.methods.builder import build_method

EDGE_QUANTILE = 0.8
FLAT_QUANTILE = 0.4


def centre_crop(image: np.ndarray, size: int) -> np.ndarray:
    """The ``size x size`` centre of an ``(H, W, 3)`` image (the whole image where it is smaller)."""
    h, w = image.shape[:2]
    y, x = max((h - size) // 2, 0), max((w - size) // 2, 0)
    return image[y : y + size, x : x + size]


def regions(target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks ``(edges, flat)`` of an ``(H, W, 3)`` target by the quantiles of its Sobel gradient magnitude."""
    grey = target.mean(axis=-1)
    gradient = np.hypot(ndimage.sobel(grey, 0), ndimage.sobel(grey, 1))
    return gradient > np.quantile(gradient, EDGE_QUANTILE), gradient < np.quantile(gradient, FLAT_QUANTILE)


def colour_errors(shown: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """CIEDE2000 (whole, edges, flat) and mean |ΔL*|, |Δ(a*, b*)| of ``shown`` against ``target``, both
    ``(H, W, 3)`` in [0, 1]."""
    lab_shown, lab_target = rgb2lab(np.clip(shown, 0.0, 1.0)), rgb2lab(target)
    delta_e = deltaE_ciede2000(lab_target, lab_shown)
    edges, flat = regions(target)
    difference = lab_shown - lab_target
    return {
        "dE": float(delta_e.mean()),
        "edges": float(delta_e[edges].mean()),
        "flat": float(delta_e[flat].mean()),
        "|dL|": float(np.abs(difference[..., 0]).mean()),
        "|dab|": float(np.hypot(difference[..., 1], difference[..., 2]).mean()),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="trained run directories (or builtin:NAME)")
    parser.add_argument("--methods", default="doe+net,doe+ensemble", help="comma-separated methods of each run")
    parser.add_argument("--images", default="chelsea,coffee", help="comma-separated built-in test photographs")
    parser.add_argument("--depths-mm", default="500,800", help="comma-separated screen depths (mm)")
    parser.add_argument("--size", type=int, default=256, help="centre crop (px)")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    depths_mm = [float(v) for v in args.depths_mm.split(",")]
    images = {name: centre_crop(load_builtin_photo(name) / 255.0, args.size) for name in args.images.split(",")}
    columns = ("dE", "edges", "flat", "|dL|", "|dab|")
    print(f"{'run':28s} {'method':14s} {'image':18s} {'depth':>6s} " + " ".join(f"{c:>7s}" for c in columns))
    for run in args.runs:
        for name in args.methods.split(","):
            method = build_method(run, name)
            for image_name, image in images.items():
                target = torch.as_tensor(image, dtype=torch.float32).permute(2, 0, 1).unsqueeze(0)
                for depth_mm in depths_mm:
                    psf = method.design.psf([depth_mm * 1e-3])
                    with torch.no_grad():
                        captured = project(target, psf)
                        x = method.compensate(target, captured, psf)
                        shown = project(x.clamp(0.0, 1.0), psf)
                    errors = colour_errors(shown[0].permute(1, 2, 0).numpy(), image)
                    print(
                        f"{str(run)[-28:]:28s} {name:14s} {image_name:18s} {depth_mm:6.0f} "
                        + " ".join(f"{errors[c]:7.2f}" for c in columns)
                    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
