"""Per-image tables of several evaluations side by side (e.g. a run before and after a change).

For each image and each (evaluation, method), the mean over the scored depths (300-800 mm) of
SSIM and of the CIEDE2000 colour difference (``de2000``), from each evaluation's ``metrics.csv``;
then the mean over the images and the worst depth (per-depth mean over the images), as
``edofproj evaluate`` reports them. Markdown on stdout.

    PYTHONPATH=src python benchmarks/per_image_tables.py LABEL=EVAL_DIR [LABEL=EVAL_DIR ...] \\
        [--methods doe+net,doe+ensemble] [--metric ssim] [--range-mm 300:800]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from edofproj.evaluation.results import MetricsTable


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("evaluations", nargs="+", metavar="LABEL=DIR")
    parser.add_argument("--methods", default="doe+net,doe+ensemble,doe+wiener,lens+cls")
    parser.add_argument("--metric", default="ssim")
    parser.add_argument("--range-mm", default="300:800")
    args = parser.parse_args()
    lo, hi = (float(v) for v in args.range_mm.split(":"))
    methods = args.methods.split(",")
    columns = []
    for item in args.evaluations:
        label, directory = item.split("=", 1)
        table = MetricsTable.read_csv(Path(directory) / "metrics.csv", ("method", "depth_mm", "image"))
        for method in methods:
            if method in table.methods():
                columns.append((f"{label} {method}", table, method))
    images = list(columns[0][1].per_image_range_means(columns[0][2], args.metric, lo, hi))
    digits = 2 if args.metric.startswith("de2000") or args.metric == "psnr" else 4
    print("| image | " + " | ".join(c[0] for c in columns) + " |")
    print("| --- |" + " ---: |" * len(columns))
    per_image = [c[1].per_image_range_means(c[2], args.metric, lo, hi) for c in columns]
    for image in images:
        print(
            f"| {image} | " + " | ".join(f"{values.get(image, float('nan')):.{digits}f}" for values in per_image) + " |"
        )
    stats = [c[1].range_stats(c[2], args.metric, lo, hi) for c in columns]
    print("| **mean** | " + " | ".join(f"**{s.mean:.{digits}f}**" for s in stats) + " |")
    print("| worst depth | " + " | ".join(f"{s.worst:.{digits}f} ({s.worst_depth_mm:.0f})" for s in stats) + " |")


if __name__ == "__main__":
    main()
