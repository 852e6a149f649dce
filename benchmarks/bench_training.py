"""Seconds per training step and peak memory of the training presets, at each preset's crop size.

    .venv/bin/python benchmarks/bench_training.py                  # cpu (8 steps) and paper (2 steps)
    .venv/bin/python benchmarks/bench_training.py --presets cpu --steps 20 --threads 1

Each preset runs ``edofproj.training.trainer.train`` in its own subprocess (so the peak
resident memory, ``ru_maxrss``, belongs to that preset alone) in a temporary run directory.
Seconds per step are the median of the logged step times after the first step (warm-up).
Substitutions, printed with the results:

* a ``folder`` data source whose folder is absent (the paper preset's DIV2K) is replaced by
  ``dead-leaves`` crops of the same size (the cost of a step does not depend on the pixels);
* a DISTS loss whose pretrained weights are absent is timed with randomly initialized VGG16
  weights (same architecture, hence the same compute and memory).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_STEPS = {"cpu": 8, "paper": 2}


def run_preset(preset: str, steps: int, threads: int) -> dict:
    """Train ``steps`` steps of ``preset`` in this process; return timings and substitutions."""
    import numpy as np
    import torch

    from edofproj.config import load_config
    from edofproj.runs.log import read_log
    from edofproj.training import losses
    from edofproj.training.trainer import train

    notes = []
    overrides = [f"train.steps={steps}", f"train.checkpoint_every={steps}", f"train.threads={threads}"]
    cfg = load_config(preset, overrides)
    if cfg.data.source == "folder" and not Path(cfg.data.folder or "").is_dir():
        cfg = load_config(preset, overrides + ["data.source=dead-leaves", "data.folder=null"])
        notes.append(f"data: dead-leaves instead of the absent folder '{load_config(preset).data.folder}'")
    if cfg.loss.perceptual == "dists" and cfg.loss.beta > 0:
        from edofproj.perceptual.dists import DISTS, dists_backbone
        from edofproj.perceptual.weights import PerceptualWeightsMissing

        try:
            DISTS.load(cfg.loss.weights_dir)
        except PerceptualWeightsMissing:
            from edofproj.perceptual.dists import DISTS_STAGE_CHANNELS

            total = sum(DISTS_STAGE_CHANNELS)
            untrained = DISTS(dists_backbone(), torch.ones(total), torch.ones(total))
            real_build_loss = losses.build_loss

            def build_loss_untrained_dists(loss_cfg):
                loss = real_build_loss(dataclasses.replace(loss_cfg, perceptual="none"))
                loss.perceptual, loss.perceptual_name = untrained, "dists"
                return loss

            losses.build_loss = build_loss_untrained_dists
            notes.append("loss: DISTS with untrained VGG16 weights (pretrained weights absent)")
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        train(cfg, Path(tmp) / "run", progress=False)
        total = time.perf_counter() - start
        seconds = np.array([row["seconds"] for row in read_log(Path(tmp) / "run" / "train_log.csv")])
    per_step = np.diff(seconds) if len(seconds) > 1 else seconds
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    return {
        "preset": preset,
        "crop": cfg.data.crop,
        "batch": cfg.train.batch_size,
        "steps": steps,
        "threads": torch.get_num_threads(),
        "first_step_s": float(seconds[0]),
        "seconds_per_step": float(np.median(per_step)),
        "session_s": total,
        "peak_rss_mib": peak_mib,
        "notes": notes,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    parser.add_argument("--steps", type=int, default=None, help="steps per preset (default: cpu 8, paper 2)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(run_preset(args.worker, args.steps, args.threads)))
        return 0
    print(
        f"{'preset':8s} {'crop':>5s} {'batch':>5s} {'threads':>7s} {'first step s':>12s} "
        f"{'s/step':>8s} {'peak RSS MiB':>12s}"
    )
    for preset in args.presets:
        steps = args.steps or DEFAULT_STEPS.get(preset, 4)
        done = subprocess.run(
            [sys.executable, __file__, "--worker", preset, "--steps", str(steps), "--threads", str(args.threads)],
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            print(f"{preset:8s} failed: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
            continue
        r = json.loads(done.stdout.strip().splitlines()[-1])
        print(
            f"{r['preset']:8s} {r['crop']:5d} {r['batch']:5d} {r['threads']:7d} {r['first_step_s']:12.2f} "
            f"{r['seconds_per_step']:8.2f} {r['peak_rss_mib']:12.0f}"
        )
        for note in r["notes"]:
            print(f"{'':8s} note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
