"""Real-time networks trained longer than a CPU allows, on the reference model's DOE, on one GPU.

    python benchmarks/gpu/realtime_search.py OUT BUDGET_S [--grid sizes|recipes] [--device cuda]

Every job of the grid trains the ``realtime`` preset on ``builtin:cpu-doe-unet``'s DOE (``edofproj
train --config realtime --set doe.path=builtin:cpu-doe-unet ...``), all jobs at once, as separate
processes sharing the GPU; each is then scored by ``edofproj evaluate RUN --methods doe+net`` on the test
images and on the validation set (``--validation``). So that a short loan of a GPU machine suffices, the
steps are sized to the budget: a probe of ``--probe-steps`` steps with every job running gives each job's
seconds per step (the training log's ``seconds`` column, its first third left out), then each job trains
``min(its target, what ends inside the budget)`` steps (rounded down to 100) and the plan is printed.
What is left of ``BUDGET_S`` after ``--reserve-s`` (start-up and the evaluation) is the training's.

Grids (every job batch 16 unless named, the preset's other keys):

* ``sizes``: 4x4 blocks 8-16 (the preset, batch 4, 6,000 steps: the calibration against the CPU),
  8-16, 32-16 (also 6,000 steps), 64-32; 2x2 blocks 8-8 and 16-16 (also batch 4, 6,000 steps).
* ``recipes``: with the ``cpu`` preset's colour augmentation (``data.colour_augment=0.3``), a faster
  network rate (``train.lr_net=3e-3``) or both, on 2x2 16-16, 2x2 8-8, 4x4 32-16 and 64-32.

Output in OUT: ``metrics_all.csv`` (every evaluation's ``metrics.csv`` rows with the job and the image
set), ``plan.txt``, ``runs.tar.gz`` (each run's config, training log and last checkpoint, each
evaluation's metrics and summary) and ``logs.tar.gz``. Summarize with ``--summarize OUT/metrics_all.csv``:
SSIM mean over the depths of ``evaluation.score_range_mm`` (300-800 mm) of the mean over the images, the
worst depth, and the mean CIEDE2000, against the reference model's figures of its card.
"""

from __future__ import annotations

import argparse
import collections
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

#: The reference model's ``doe+net`` SSIM (mean, worst depth) from its card: test images, validation set.
REFERENCE = {"test": (0.9602, 0.9157), "validation": (0.8769, 0.8293)}
SCORE_RANGE_MM = (300, 800)
COLOUR = "data.colour_augment=0.3"
FAST = "train.lr_net=3e-3"
B2 = "net.block_px=2"
GRIDS: dict[str, list[tuple[str, list[str], int]]] = {
    "sizes": [
        ("b4_8-16_batch4", ["net.widths=[8,16]", "train.batch_size=4"], 6000),
        ("b4_8-16", ["net.widths=[8,16]"], 30000),
        ("b4_32-16", ["net.widths=[32,16]"], 30000),
        ("b4_32-16_6k", ["net.widths=[32,16]"], 6000),
        ("b4_64-32", ["net.widths=[64,32]"], 30000),
        ("b2_8-8", [B2, "net.widths=[8,8]"], 30000),
        ("b2_16-16", [B2, "net.widths=[16,16]"], 30000),
        ("b2_16-16_batch4", [B2, "net.widths=[16,16]", "train.batch_size=4"], 6000),
    ],
    "recipes": [
        ("b2_16-16_colour", [B2, "net.widths=[16,16]", COLOUR], 30000),
        ("b2_16-16_fast", [B2, "net.widths=[16,16]", FAST], 30000),
        ("b2_16-16_colour_fast", [B2, "net.widths=[16,16]", COLOUR, FAST], 30000),
        ("b2_8-8_colour_fast", [B2, "net.widths=[8,8]", COLOUR, FAST], 30000),
        ("b4_32-16_colour", ["net.widths=[32,16]", COLOUR], 30000),
        ("b4_64-32_colour", ["net.widths=[64,32]", COLOUR], 30000),
        ("b4_64-32_fast", ["net.widths=[64,32]", FAST], 30000),
        ("b4_64-32_colour_fast", ["net.widths=[64,32]", COLOUR, FAST], 30000),
    ],
}
CLI = [sys.executable, "-m", "edofproj.cli"]


def train_command(run: Path, overrides: list[str], steps: int, device: str) -> list[str]:
    sets = [
        "doe.path=builtin:cpu-doe-unet",
        f"train.device={device}",
        "train.validate_every=0",
        "train.batch_size=16",
        "train.keep_checkpoints=2",
        # the preset's warm-up (300 of 6,000 steps) scaled to shorter runs (a probe): no phase shorter than it
        f"train.warmup_steps={min(300, steps // 20)}",
        *overrides,
        f"train.steps={steps}",
        f"train.checkpoint_every={max(steps // 4, 1)}",
    ]
    return [
        *CLI,
        "train",
        "--config",
        "realtime",
        *(a for s in sets for a in ("--set", s)),
        "--out",
        str(run),
        "--quiet",
    ]


def start(command: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=log.open("a"), stderr=subprocess.STDOUT)


def seconds_per_step(run: Path) -> float | None:
    """Seconds per step from the training log, its first third (start-up, warm-up) left out."""
    log = run / "train_log.csv"
    if not log.is_file():
        return None
    with log.open() as f:
        seconds = [float(row["seconds"]) for row in csv.DictReader(f)]
    first = len(seconds) // 3
    return (seconds[-1] - seconds[first]) / max(len(seconds) - 1 - first, 1)


def wait_all(procs: list[subprocess.Popen], until: float) -> None:
    for proc in procs:
        try:
            proc.wait(timeout=max(5.0, until - time.time()))
        except subprocess.TimeoutExpired:
            proc.kill()
            print(f"killed at the deadline: {str(proc.args)[:160]}", flush=True)


def search(out: Path, budget_s: float, grid: str, device: str, probe_steps: int, reserve_s: float) -> None:
    work = Path(os.environ.get("WORK", "/tmp/realtime_search"))
    work.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", "2")  # many processes share the host's cores
    jobs = GRIDS[grid]
    t0 = time.time()
    probes = [start(train_command(work / f"{n}_probe", o, probe_steps, device), out / f"{n}.log") for n, o, _ in jobs]
    wait_all(probes, t0 + budget_s)
    rates = {n: r for n, _, _ in jobs if (r := seconds_per_step(work / f"{n}_probe")) is not None}
    print(
        f"probe {time.time() - t0:.0f} s; s/step with every job running: "
        + ", ".join(f"{n} {r * 1e3:.1f} ms" for n, r in rates.items()),
        flush=True,
    )
    train_s = budget_s - (time.time() - t0) - reserve_s
    plan = []
    for name, overrides, target in jobs:
        if name in rates:
            steps = max(100, int(min(target, 0.92 * (train_s - 25) / rates[name])) // 100 * 100)
            plan.append((name, overrides, steps))
            print(f"{name}: {steps} steps (target {target}, predicted {steps * rates[name]:.0f} s)", flush=True)
    t1 = time.time()
    runs = [start(train_command(work / n, o, s, device), out / f"{n}.log") for n, o, s in plan]
    wait_all(runs, t1 + train_s)
    print(f"training {time.time() - t1:.0f} s", flush=True)
    t2 = time.time()
    evaluations = []
    for name, _, _ in plan:
        for image_set in ("test", "validation"):
            eval_dir = work / f"eval_{name}_{image_set}"
            command = [
                *CLI,
                "evaluate",
                str(work / name),
                "--methods",
                "doe+net",
                "--device",
                device,
                "--out",
                str(eval_dir),
                "--quiet",
                *(["--validation"] if image_set == "validation" else []),
            ]
            evaluations.append((name, image_set, eval_dir, start(command, out / f"{name}.log")))
    wait_all([e[3] for e in evaluations], t0 + budget_s - 10)
    print(f"evaluation {time.time() - t2:.0f} s", flush=True)
    rows = []
    for name, image_set, eval_dir, _ in evaluations:
        if (eval_dir / "metrics.csv").is_file():
            with (eval_dir / "metrics.csv").open() as f:
                rows += [{"job": name, "set": image_set, **row} for row in csv.DictReader(f)]
    if rows:
        with (out / "metrics_all.csv").open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    (out / "plan.txt").write_text(repr({"rates_s": rates, "plan": plan}) + "\n")
    keep = [
        str(p.relative_to(work))
        for pattern in (
            "*/config.yaml",
            "*/train_log.csv",
            "*/checkpoints/last.pt",
            "eval_*/metrics.csv",
            "eval_*/summary.md",
        )
        for p in work.glob(pattern)
        if "_probe" not in str(p)
    ]
    subprocess.run(["tar", "-czf", str(out / "runs.tar.gz"), "-C", str(work), *keep], check=False)
    logs = sorted(p.name for p in out.glob("*.log"))
    subprocess.run(["tar", "-czf", str(out / "logs.tar.gz"), "-C", str(out), *logs], check=False)
    for name in logs:
        (out / name).unlink()
    print(f"total {time.time() - t0:.0f} s", flush=True)


def summarize(metrics_csv: Path) -> None:
    ssim: dict[tuple[str, str, int], list[float]] = collections.defaultdict(list)
    colour: dict[tuple[str, str], list[float]] = collections.defaultdict(list)
    with metrics_csv.open() as f:
        for row in csv.DictReader(f):
            depth_mm = round(float(row["depth_mm"]))
            if row["method"] == "doe+net" and SCORE_RANGE_MM[0] <= depth_mm <= SCORE_RANGE_MM[1]:
                ssim[(row["job"], row["set"], depth_mm)].append(float(row["ssim"]))
                colour[(row["job"], row["set"])].append(float(row["de2000"]))
    print(
        "| job | test: mean / worst (depth) | − reference | ΔE2000 | validation: mean / worst (depth) | − reference | ΔE2000 |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for job in dict.fromkeys(k[0] for k in ssim):
        cells = []
        for image_set in ("test", "validation"):
            by_depth = {z: sum(v) / len(v) for (j, s, z), v in ssim.items() if j == job and s == image_set}
            if not by_depth:
                cells.append("– | – | –")
                continue
            mean, worst_z = sum(by_depth.values()) / len(by_depth), min(by_depth, key=by_depth.__getitem__)
            ref_mean, ref_worst = REFERENCE[image_set]
            de = colour[(job, image_set)]
            cells.append(
                f"{mean:.4f} / {by_depth[worst_z]:.4f} ({worst_z}) | {mean - ref_mean:+.4f} / "
                f"{by_depth[worst_z] - ref_worst:+.4f} | {sum(de) / len(de):.2f}"
            )
        print(f"| {job} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, nargs="?")
    parser.add_argument("budget_s", type=float, nargs="?")
    parser.add_argument("--grid", choices=sorted(GRIDS), default="sizes")
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--probe-steps", type=int, default=300)
    parser.add_argument("--reserve-s", type=float, default=120.0, help="seconds kept for start-up and evaluation")
    parser.add_argument(
        "--summarize", type=Path, metavar="METRICS_CSV", help="print the table of a search's metrics_all.csv"
    )
    args = parser.parse_args()
    if args.summarize:
        summarize(args.summarize)
    elif args.out is None or args.budget_s is None:
        parser.error("OUT and BUDGET_S are needed (or --summarize METRICS_CSV)")
    else:
        search(args.out, args.budget_s, args.grid, args.device, args.probe_steps, args.reserve_s)


if __name__ == "__main__":
    main()
