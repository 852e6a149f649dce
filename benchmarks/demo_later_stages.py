"""Seconds of each of the demo's stages after training, on the runs of a finished demo.

    PYTHONPATH=src python benchmarks/demo_later_stages.py DEMO OUT [--profile]

``DEMO``: the output folder of ``edofproj demo`` (its runs ``doe_net/``, ``lens_net/``, ... are copied to
``OUT``, which must not exist; ``DEMO`` is left as it is). Runs, as ``edofproj demo`` does after its
training stage and with its settings: the evaluation of the demo's methods, the timing stage, the 3-D
scene, the textured surface and the report's documents, each timed by the wall clock, on 2 torch
threads (the demo's). ``--profile`` also writes ``OUT/<stage>.prof`` (``cProfile``, main thread only:
the evaluation's tasks run on worker threads) and times the report twice, unprofiled then profiled.
The header names the CPU's instruction sets.
"""

from __future__ import annotations

import argparse
import cProfile
import shutil
import sys
import time
from pathlib import Path

import torch

from edofproj.application import demo
from edofproj.evaluation.pipeline import evaluate_run
from edofproj.machine import instruction_sets
from edofproj.progress import StageProgress
from edofproj.reporting.writeup import write_documents


def timed(name: str, function, out: Path, profile: bool):
    """Run ``function``, print its wall seconds (and keep its profile with ``profile``); return its result."""
    profiler = cProfile.Profile() if profile else None
    start = time.perf_counter()
    if profiler is not None:
        profiler.enable()
    result = function()
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(out / f"{name}.prof")
    print(f"{name:10s} {time.perf_counter() - start:7.1f} s{' (profiled)' if profile else ''}", flush=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("demo", type=Path, help="a finished demo's output folder")
    parser.add_argument("out", type=Path, help="a new folder for the copies of its runs and what the stages write")
    parser.add_argument("--profile", action="store_true", help="cProfile each stage into OUT/<stage>.prof")
    args = parser.parse_args()
    if args.out.exists():
        parser.error(f"{args.out} exists: give a new folder")
    runs = [d for d in sorted(args.demo.iterdir()) if (d / "config.yaml").is_file()]
    if not any(d.name == demo.OURS_RUN_DIR for d in runs):
        parser.error(f"{args.demo} holds no {demo.OURS_RUN_DIR}/ run: not a demo's output folder")
    args.out.mkdir(parents=True)
    for run in runs:
        shutil.copytree(run, args.out / run.name)
    torch.set_num_threads(2)
    print(f"torch {torch.__version__}, 2 threads [{instruction_sets()}], wall seconds", flush=True)
    out, profile = args.out, args.profile
    methods = demo.demo_methods(demo.FULL, None)
    evaluation = timed(
        "evaluation",
        lambda: evaluate_run(out / demo.OURS_RUN_DIR, out_dir=out, methods=methods, baselines_dir=out),
        out,
        profile,
    )
    quiet = StageProgress("demo", enabled=False)
    timings = timed("timing", lambda: demo.timing_rows(evaluation, demo.FULL), out, profile)
    for row in timings:
        print(
            f"  {row.method} ({row.backend}) {row.height}x{row.width}: {row.median_ms:.1f} ms, {row.repeats} frame(s)"
        )
    timed("scene", lambda: demo.scene_section(out, evaluation.methods, False, quiet), out, profile)
    timed("surface", lambda: demo.surface_section(out, evaluation.methods, quiet), out, profile)
    if profile:
        timed("report", lambda: write_documents(evaluation, title="demo report", preface=[], extra=[]), out, False)
    timed("report", lambda: write_documents(evaluation, title="demo report", preface=[], extra=[]), out, profile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
