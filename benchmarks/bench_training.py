"""Seconds per training step and peak memory of the training presets, at each preset's crop size;
with ``--stages``, the seconds of each stage of one step.

    .venv/bin/python benchmarks/bench_training.py                  # cpu (8 steps) and paper (2 steps)
    .venv/bin/python benchmarks/bench_training.py --presets cpu --steps 20 --threads 1
    .venv/bin/python benchmarks/bench_training.py --stages --presets cpu realtime --threads 1
    .venv/bin/python benchmarks/bench_training.py --stages --presets cpu --threads 1 --precision float32

``--stages`` times each stage of a step of a training session (:class:`~edofproj.training.trainer`'s
session, built as ``edofproj train`` builds it) on its own, forward and backward together, with the
shapes of the real step: data (crops, depths), the PSFs (simulated for a trained DOE, looked up in the
table for a fixed one), image formation (the two projections and the camera), the network, the loss,
gradient clipping with the optimizer step, and the checkpoint amortized over ``train.checkpoint_every``
steps; then whole steps. The median of ``--repeats`` runs is printed, as process CPU seconds with one
thread (robust to other processes on a shared machine: a one-thread process is charged only while it
runs) and as wall seconds otherwise. The stages add up to the step less Python and autograd overhead.

``--precision`` sets the network's arithmetic: ``config`` (the preset's ``train.mixed_precision``;
the ``cpu`` preset's ``auto`` is bfloat16 autocast where the CPU computes bfloat16 natively,
AVX-512-BF16 or AMX, float32 elsewhere), ``float32`` (autocast off: what an AVX2-only CPU runs) or
``bf16``. The header names the CPU's instruction sets (:mod:`edofproj.machine`) and each result the
precision that ran.

Each preset runs ``edofproj.training.trainer.train`` in its own subprocess (so the peak
resident memory, ``ru_maxrss``, belongs to that preset alone) in a temporary run directory.
Seconds per step are the median of the logged step times after the first step (warm-up).
Substitutions, printed with the results:

* a ``folder`` data source whose folder is absent (the paper preset's DIV2K) is replaced by
  ``dead-leaves`` crops of the same size (the cost of a step does not depend on the pixels);
* a fixed DOE whose file is absent (the realtime preset's ``runs/demo/doe_net/doe.npz``, there
  once ``edofproj demo`` has run in the current folder) is replaced by the DOE of the shipped
  reference run, ``builtin:cpu-doe-net`` (a DOE of the same kind and size: the same cost);
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
#: ``--precision`` -> config overrides (module docstring).
PRECISION_OVERRIDES = {"config": [], "float32": ["train.mixed_precision=none"], "bf16": ["train.mixed_precision=bf16"]}
#: The DOE a preset's absent fixed DOE file is replaced by (module docstring).
SHIPPED_DOE = "builtin:cpu-doe-net"


def precision_that_runs(cfg) -> str:
    """``bf16`` (bfloat16 autocast) or ``float32``: the network's arithmetic of ``cfg`` on this machine."""
    import torch

    from edofproj.training.end_to_end import resolve_mixed_precision

    device = torch.device("cuda" if cfg.train.device != "cpu" and torch.cuda.is_available() else "cpu")
    return "bf16" if resolve_mixed_precision(cfg.train.mixed_precision, device) == "bf16" else "float32"


def substitutions(preset: str, overrides: list[str]) -> tuple[list[str], list[str]]:
    """The overrides that stand in for what ``preset`` (with ``overrides``) needs and this machine
    lacks (module docstring), and a note for each."""
    from edofproj.config import load_config
    from edofproj.doe.factory import resolve_doe_file
    from edofproj.errors import EdofprojError

    extra, notes = [], []
    cfg = load_config(preset, overrides)
    if cfg.data.source == "folder" and not Path(cfg.data.folder or "").is_dir():
        extra += ["data.source=dead-leaves", "data.folder=null"]
        notes.append(f"data: dead-leaves instead of the absent folder '{cfg.data.folder}'")
    if cfg.doe.kind == "file":
        try:
            resolve_doe_file(str(cfg.doe.path))
        except EdofprojError:
            extra.append(f"doe.path={SHIPPED_DOE}")
            notes.append(f"doe: the DOE of {SHIPPED_DOE} instead of the absent '{cfg.doe.path}'")
    return extra, notes


def stage_seconds(preset: str, threads: int, repeats: int, overrides: list[str]) -> dict:
    """Median seconds of each stage of one training step of ``preset`` (module docstring)."""
    import warnings

    import numpy as np
    import torch

    from edofproj.config import load_config
    from edofproj.imaging.projection import project
    from edofproj.training.camera import camera_capture
    from edofproj.training.distributed import setup_process_group
    from edofproj.training.sampling import sample_depths_m, sample_images
    from edofproj.training.trainer import _clip, _Session, loss_terms

    torch.set_num_threads(threads)
    clock = time.process_time if threads == 1 else time.perf_counter
    warnings.simplefilter("ignore")
    extra, notes = substitutions(preset, overrides)
    cfg = load_config(preset, overrides + extra)

    def median(fn, n=repeats):
        fn()
        times = []
        for _ in range(n):
            start = clock()
            fn()
            times.append(clock() - start)
        return float(np.median(times))

    with tempfile.TemporaryDirectory() as tmp:
        session = _Session(cfg, Path(tmp) / "run", setup_process_group("cpu"))
        c, step = cfg, 1

        def draw():
            depths = sample_depths_m(
                c.train.seed, step, session.shard, c.psf.depth_min_m, c.psf.depth_max_m,
                c.train.depth_sampling, c.train.depth_spacing,
            )  # fmt: skip
            return depths, sample_images(session.source, c.train.seed, step, session.shard, c.data.crop)

        depths, images = draw()
        source = session.model.psf_source
        psf = source(depths).detach()

        def psfs():
            p = source(depths)
            if session.doe_params:
                torch.autograd.grad(p, session.doe_params, torch.ones_like(p))

        def imaging():
            x = images.clone().requires_grad_(True)
            kernel = psf.clone().requires_grad_(True)
            shown = project(x, kernel) + camera_capture(project(x, kernel))
            torch.autograd.grad(shown.sum(), [x, kernel])

        captured = project(images, psf)

        def network():
            out = session.model._compensate(images, captured)
            out.sum().backward()

        projected = captured.clone().requires_grad_(True)

        def loss():
            loss_terms(session.loss_fn, cfg, projected, images)[0].backward()

        def optimizer():
            norms = [_clip(p, cfg.train.grad_clip) for p in (session.doe_params, session.net_params) if p]
            [float(n) for n in norms]
            session.optimizer.step()

        stages = {
            "data": median(draw),
            "psf": median(psfs),
            "imaging": median(imaging),
            "network": median(network),
            "loss": median(loss),
            "optimizer": median(optimizer),
            "checkpoint": median(session.save, 3) / cfg.train.checkpoint_every,
        }
        stages["step"] = median(session.train_step)
    return {
        "preset": preset,
        "threads": torch.get_num_threads(),
        "clock": clock.__name__,
        "precision": precision_that_runs(cfg),
        "stages": stages,
        "notes": notes,
    }


def run_preset(preset: str, steps: int, threads: int, overrides: list[str]) -> dict:
    """Train ``steps`` steps of ``preset`` in this process; return timings and substitutions."""
    import numpy as np
    import torch

    from edofproj.config import load_config
    from edofproj.runs.log import read_log
    from edofproj.training import losses
    from edofproj.training.trainer import train

    # a learning-rate warm-up does not change a step's cost, and one longer than the timed steps is refused
    overrides = overrides + [
        f"train.steps={steps}",
        f"train.checkpoint_every={steps}",
        f"train.threads={threads}",
        "train.warmup_steps=0",
    ]
    extra, notes = substitutions(preset, overrides)
    cfg = load_config(preset, overrides + extra)
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
        "precision": precision_that_runs(cfg),
        "notes": notes,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    parser.add_argument("--steps", type=int, default=None, help="steps per preset (default: cpu 8, paper 2)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--stages", action="store_true", help="seconds of each stage of a step (module docstring)")
    parser.add_argument("--repeats", type=int, default=10, help="--stages: runs of each stage (median)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override (repeatable)")
    parser.add_argument(
        "--precision",
        choices=tuple(PRECISION_OVERRIDES),
        default="config",
        help="the network's arithmetic: the preset's, float32 (bf16 autocast off) or bf16 (module docstring)",
    )
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.set = args.set + PRECISION_OVERRIDES[args.precision]
    if args.worker:
        if args.stages:
            print(json.dumps(stage_seconds(args.worker, args.threads or 1, args.repeats, args.set)))
        else:
            print(json.dumps(run_preset(args.worker, args.steps, args.threads, args.set)))
        return 0
    from edofproj.machine import instruction_sets

    print(f"CPU: {instruction_sets()}")
    if args.stages:
        return print_stages(args)
    print(
        f"{'preset':8s} {'crop':>5s} {'batch':>5s} {'threads':>7s} {'first step s':>12s} "
        f"{'s/step':>8s} {'peak RSS MiB':>12s}  precision"
    )
    for preset in args.presets:
        steps = args.steps or DEFAULT_STEPS.get(preset, 4)
        command = [sys.executable, __file__, "--worker", preset, "--steps", str(steps), "--threads", str(args.threads)]
        done = subprocess.run(
            command + [item for value in args.set for item in ("--set", value)], capture_output=True, text=True
        )
        if done.returncode != 0:
            print(f"{preset:8s} failed: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
            continue
        r = json.loads(done.stdout.strip().splitlines()[-1])
        print(
            f"{r['preset']:8s} {r['crop']:5d} {r['batch']:5d} {r['threads']:7d} {r['first_step_s']:12.2f} "
            f"{r['seconds_per_step']:8.2f} {r['peak_rss_mib']:12.0f}  {r['precision']}"
        )
        for note in r["notes"]:
            print(f"{'':8s} note: {note}")
    return 0


def print_stages(args) -> int:
    """Run :func:`stage_seconds` for each preset in its own process and print one column per preset."""
    results = []
    for preset in args.presets:
        command = [sys.executable, __file__, "--worker", preset, "--stages", "--threads", str(args.threads or 1)]
        command += ["--repeats", str(args.repeats)] + [item for value in args.set for item in ("--set", value)]
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            print(f"{preset}: failed: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
            continue
        results.append(json.loads(done.stdout.strip().splitlines()[-1]))
    if not results:
        return 1
    print(f"ms per step ({results[0]['clock']}, {results[0]['threads']} thread(s), median of {args.repeats})")
    print(f"{'precision':12s}" + "".join(f"{r['precision']:>12s}" for r in results))
    print(f"{'stage':12s}" + "".join(f"{r['preset']:>12s}" for r in results))
    for stage in results[0]["stages"]:
        print(f"{stage:12s}" + "".join(f"{1e3 * r['stages'][stage]:12.1f}" for r in results))
    total = [sum(v for k, v in r["stages"].items() if k != "step") for r in results]
    print(f"{'sum':12s}" + "".join(f"{1e3 * t:12.1f}" for t in total))
    for r in results:
        for note in r["notes"]:
            print(f"{r['preset']}: note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
