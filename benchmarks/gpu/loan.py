"""One lease of a GPU machine, used to the end: train for the time there is, score, bring the run back.

    python3 benchmarks/gpu/loan.py OUT --budget-s SECONDS [--config paper] [--set KEY=VALUE ...]
                                      [--resume PACK.pack.json] [--device cuda] [--sets test,validation]

``bash benchmarks/gpu/run_gpu_checks.sh loan`` runs it after installing what the GPU image lacks (its
header). Every stage is bounded by what is left of ``--budget-s`` (seconds from this script's start),
and whatever a stage leaves (a checkpoint, a table) is written to OUT even when a later stage fails:

1. **machine**: the GPU as ``nvidia-smi`` names it (memory, driver), PyTorch and CUDA, the CPU and its
   instruction sets (:func:`edofproj.machine.instruction_sets`);
2. **train**: ``edofproj train --time-budget T`` on a new run of ``--config`` (the ``paper`` preset by
   default, with :data:`LOAN_OVERRIDES` that the loan machine needs, then ``--set``), or ``--resume`` of
   the run a previous loan packed (unpacked first: :func:`edofproj.runs.pack.unpack_run`). ``T`` is what is
   left after ``--reserve-s`` for scoring and packing; the session checkpoints where it stops, and a
   session that overruns is killed when only ``--pack-s`` is left (the run then keeps its last
   periodic checkpoint, and the scoring is skipped);
3. **score**: ``edofproj evaluate RUN --methods METHODS`` on the run's held-out test images and on the
   validation set (``--validation``), each bounded by the time left;
4. **record** in OUT, within the machine's limits on what comes back (:data:`OUT_MAX_FILES` files of at
   most :data:`OUT_MAX_FILE_BYTES` bytes, :data:`OUT_MAX_TOTAL_BYTES` in all, counting what is already
   in OUT):

   * ``record.json``: the machine; the command lines; steps before and after, whether the budget ended the
     session; the step rate (median seconds per step of this session's log, its first
     :data:`WARMUP_STEPS` steps left out), samples per second (``train.batch_size`` over it), peak GPU
     memory; the losses (first, last, mean of the last tenth); the checkpoint's bytes; the
     evaluation table (per image set and method: SSIM, PSNR and CIEDE2000, the mean over the scored
     depths of the mean over the images, and SSIM's worst depth); the pack written and why;
   * ``results.tar.gz``: ``train_log.csv``, ``validation_log.csv``, each evaluation's ``metrics.csv`` and
     ``summary.md``, and this script's log ``loan.log``;
   * ``run.pack.json`` and ``run.tar.000`` ...: the run (:mod:`edofproj.runs.pack`), resumable
     (with the optimizer's state) when it fits in the parts left, else slimmed to the network and the
     DOE (evaluate, ship, fine-tune; not resume), else none (said in the record).

The next loan continues the run bit for bit: copy the files of OUT into a folder of the repository
that git ignores, carry it, and pass ``--resume FOLDER/run.pack.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tarfile
import time
from pathlib import Path

#: What comes back from a loan's OUT: files, bytes per file, bytes in all (the device's README; MB, not
#: MiB, so that the limit holds whichever unit it means).
OUT_MAX_FILES = 8
OUT_MAX_FILE_BYTES = 16_000_000
OUT_MAX_TOTAL_BYTES = 64_000_000
#: Bytes kept for ``record.json`` (written last).
RECORD_BYTES = 200_000
#: Steps of a session left out of its step rate (CUDA's and cuDNN's first calls, allocations).
WARMUP_STEPS = 10
#: What the ``paper`` preset needs on the loan machine, before ``--set``: DIV2K and the DISTS weights are
#: not there (the built-in photographs, 1 - MS-SSIM instead), 256-pixel crops (no built-in photograph has
#: 1,024 on both sides), batch 4, the network in bf16.
LOAN_OVERRIDES = (
    "data.source=builtin",
    "data.test_fraction=0.3",
    "data.crop=256",
    "loss.perceptual=ms-ssim",
    "train.batch_size=4",
    "train.mixed_precision=bf16",
)
CLI = [sys.executable, "-m", "edofproj.cli"]


class Loan:
    """The script's clock, log and OUT."""

    def __init__(self, out: Path, work: Path, budget_s: float):
        self.t0 = time.monotonic()
        self.budget_s = budget_s
        self.out = out
        self.work = work
        out.mkdir(parents=True, exist_ok=True)
        work.mkdir(parents=True, exist_ok=True)
        self.preexisting = [p for p in out.iterdir() if p.is_file()]
        self.log_path = work / "loan.log"
        self.commands: list[str] = []

    def left_s(self) -> float:
        return self.budget_s - (time.monotonic() - self.t0)

    def say(self, text: str) -> None:
        line = f"[loan {time.monotonic() - self.t0:6.0f} s] {text}"
        print(line, flush=True)
        with self.log_path.open("a", encoding="utf-8") as handle:
            handle.write(line + "\n")

    def run(self, command: list[str], timeout_s: float) -> tuple[int, str]:
        """Run ``command`` for at most ``timeout_s`` seconds; its output goes to the log and is returned."""
        self.commands.append(" ".join(["edofproj", *command[len(CLI) :]] if command[: len(CLI)] == CLI else command))
        self.say("$ " + self.commands[-1])
        if timeout_s < 1:
            self.say("skipped: no time left")
            return 124, ""
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
            code, output = done.returncode, done.stdout + done.stderr
        except subprocess.TimeoutExpired as exc:
            code = 124
            output = _text(exc.stdout) + _text(exc.stderr) + f"\nkilled after {timeout_s:.0f} s\n"
        with self.log_path.open("a", encoding="utf-8") as handle:
            handle.write(output)
        print(output[-3000:], end="" if output.endswith("\n") else "\n", flush=True)
        return code, output


def _text(value) -> str:
    if value is None:
        return ""
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


# ----------------------------------------------------------------------------- 1. machine


def machine() -> dict:
    """The GPU (``nvidia-smi``'s name, memory, driver; None without one), PyTorch, CUDA, the CPU."""
    import torch

    from edofproj.machine import instruction_sets

    gpu = None
    if shutil.which("nvidia-smi"):
        query = ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"]
        done = subprocess.run(query, capture_output=True, text=True, check=False)
        gpu = done.stdout.strip() or done.stderr.strip() or None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "gpu": gpu,
        "torch": torch.__version__,
        "cuda": torch.version.cuda,
        "cuda_available": torch.cuda.is_available(),
        "cpu": cpu,
        "cpu_cores": os.cpu_count(),
        "instruction_sets": instruction_sets(),
    }


# ----------------------------------------------------------------------------- 2. train


def train_command(run: Path, args, time_budget_s: float) -> list[str]:
    """The ``edofproj train`` command of the session: a new run of ``args.config``, or ``--resume``."""
    command = [*CLI, "train", "--out", str(run), "--quiet", "--time-budget", f"{time_budget_s:.0f}"]
    if args.stop_after is not None:
        command += ["--stop-after", str(args.stop_after)]
    loan_overrides = () if args.resume or args.no_loan_overrides else LOAN_OVERRIDES
    sets = [*loan_overrides, *args.set]  # a resumed run takes only the keys it may change (train.steps, ...)
    sets.append(f"train.device={args.device}")  # a resumed run may change its device only
    if args.resume:
        command.append("--resume")
    else:
        command += ["--config", args.config]
    return command + [a for s in sets for a in ("--set", s)]


def training_figures(run: Path, start_step: int, batch_size: int) -> dict:
    """Step rate, samples per second and losses of the session's rows of ``train_log.csv`` (steps after
    ``start_step``): median seconds per step after :data:`WARMUP_STEPS`, the loss of the first and last step,
    the mean of the last tenth."""
    from edofproj.runs.log import read_log

    path = run / "train_log.csv"
    rows = [r for r in read_log(path) if r["step"] > start_step] if path.is_file() else []
    figures: dict = {"steps_logged": len(rows)}
    if not rows:
        return figures
    seconds = [r["seconds"] for r in rows]
    gaps = [b - a for a, b in zip(seconds, seconds[1:])][WARMUP_STEPS:]
    if gaps:
        s_per_step = statistics.median(gaps)
        figures.update(
            s_per_step=s_per_step,
            steps_per_s=1 / s_per_step if s_per_step > 0 else None,
            samples_per_s=batch_size / s_per_step if s_per_step > 0 else None,
            rate_over_steps=len(gaps),
        )
    losses = [r["loss"] for r in rows]
    tail = losses[-max(1, len(losses) // 10) :]
    figures.update(
        first_step=int(rows[0]["step"]),
        last_step=int(rows[-1]["step"]),
        loss_first=losses[0],
        loss_last=losses[-1],
        loss_mean_last_tenth=sum(tail) / len(tail),
        run_training_s=seconds[-1],
    )
    return figures


# ----------------------------------------------------------------------------- 3. score


def evaluation_table(metrics_csv: Path, cfg) -> dict:
    """``{method: {ssim_mean, ssim_worst, ssim_worst_depth_mm, psnr_mean, de2000_mean, depths}}`` over the
    scored depths (:func:`edofproj.methods.compensators.score_range_mm`)."""
    from edofproj.evaluation.results import MetricsTable
    from edofproj.methods.compensators import score_range_mm
    from edofproj.methods.depth_ranges import scored_range_mm

    table = MetricsTable.read_csv(metrics_csv, ("method", "depth_mm", "image"))
    lo, hi = scored_range_mm(table.depths_mm(), score_range_mm(cfg))
    result = {}
    for method in table.methods():
        ssim = table.range_stats(method, "ssim", lo, hi)
        result[method] = {
            "ssim_mean": ssim.mean,
            "ssim_worst": ssim.worst,
            "ssim_worst_depth_mm": ssim.worst_depth_mm,
            "psnr_mean": table.range_stats(method, "psnr", lo, hi).mean,
            "de2000_mean": table.range_stats(method, "de2000", lo, hi).mean,
            "depths": ssim.depths,
            "range_mm": [lo, hi],
        }
    return result


# ----------------------------------------------------------------------------- 4. record


def pack_room(out: Path) -> tuple[int, int]:
    """``(parts, bytes per part)`` that OUT has room for: the files and bytes that are not taken yet, less
    the manifest and ``record.json`` (one file each, :data:`RECORD_BYTES` together)."""
    present = [p for p in out.iterdir() if p.is_file() and p.name != "record.json"]
    files = OUT_MAX_FILES - len(present) - 2
    room = OUT_MAX_TOTAL_BYTES - sum(p.stat().st_size for p in present) - RECORD_BYTES
    parts = min(files, math.ceil(room / OUT_MAX_FILE_BYTES)) if room > 0 else 0
    return parts, min(OUT_MAX_FILE_BYTES, room // parts) if parts > 0 else 0


def pack(loan: Loan, run: Path) -> dict:
    """The run packed into OUT: resumable if it fits, else slimmed, else nothing (the reasons recorded)."""
    from edofproj.errors import EdofprojError
    from edofproj.runs.pack import pack_run

    parts, part_bytes = pack_room(loan.out)
    checkpoint = run / "checkpoints" / "last.pt"
    result: dict = {"checkpoint_bytes": checkpoint.stat().st_size if checkpoint.is_file() else None}
    refusals = []
    for resumable in (True, False):
        if parts < 1:
            refusals.append("no room in OUT for a pack")
            break
        try:
            packed = pack_run(run, loan.out, "run", part_bytes=part_bytes, max_parts=parts, resumable=resumable)
        except EdofprojError as exc:
            refusals.append(str(exc))
            continue
        result.update(
            manifest=packed.manifest.name,
            parts=[p.name for p in packed.parts],
            resumable=packed.resumable,
            step=packed.step,
            tar_bytes=packed.tar_bytes,
        )
        break
    result["refused"] = refusals
    for line in refusals:
        loan.say(f"pack: {line}")
    return result


def results_archive(loan: Loan, run: Path, evaluations: dict[str, Path]) -> None:
    members = [(run / name, name) for name in ("train_log.csv", "validation_log.csv", "config.yaml")]
    for image_set, folder in evaluations.items():
        members += [(folder / name, f"eval_{image_set}/{name}") for name in ("metrics.csv", "summary.md")]
    members.append((loan.log_path, "loan.log"))
    with tarfile.open(loan.out / "results.tar.gz", "w:gz") as tar:
        for path, name in members:
            if path.is_file():
                tar.add(str(path), arcname=name)


# ----------------------------------------------------------------------------- the loan


def train_stage(loan: Loan, args, record: dict, run: Path) -> None:
    """Unpack the run to resume (``--resume``) or start a new one, train it for the time there is, and
    record the session's figures."""
    from edofproj.errors import EdofprojError
    from edofproj.runs import saved_config
    from edofproj.runs.checkpoint import load_checkpoint
    from edofproj.runs.pack import read_manifest, unpack_run

    start_step = 0
    if args.resume:
        if not read_manifest(args.resume)["resumable"]:
            raise EdofprojError(
                f"{args.resume} holds a checkpoint slimmed to the network and the DOE (no optimizer state): "
                "it can be evaluated or fine-tuned, not resumed"
            )
        unpack_run(args.resume, run)
        start_step = int(load_checkpoint(run / "checkpoints" / "last.pt")["step"])
        loan.say(f"unpacked {args.resume} at step {start_step}")
    train_s = loan.left_s() - args.reserve_s
    record["train_budget_s"] = train_s
    code, output = 124, ""
    if train_s < 10:
        loan.say(f"no time to train ({train_s:.0f} s left after the reserve of {args.reserve_s:.0f} s)")
    else:
        started = time.monotonic()
        # a session that overruns may take the scoring's time, never the packing's
        code, output = loan.run(train_command(run, args, train_s), loan.left_s() - args.pack_s)
        record["train_wall_s"] = time.monotonic() - started
    record["train_exit_code"] = code
    last = run / "checkpoints" / "last.pt"
    record["training"] = {
        "start_step": start_step,
        "step": int(load_checkpoint(last)["step"]) if last.is_file() else 0,
        "stopped_at_time_budget": "stopped at the time budget" in output,
        "peak_gpu_memory_gib": _peak_gib(output),
    }
    if (run / "config.yaml").is_file():
        cfg = saved_config(run)
        record["config"] = {"name": cfg.name, "steps": cfg.train.steps, "batch_size": cfg.train.batch_size}
        record["training"].update(training_figures(run, start_step, cfg.train.batch_size))


def evaluate_stage(loan: Loan, args, record: dict, run: Path) -> dict[str, Path]:
    """Score the run on each image set of ``--sets`` in the time left (but ``--pack-s``); the evaluation
    folders that hold a ``metrics.csv``."""
    from edofproj.runs import saved_config

    cfg = saved_config(run)
    evaluations = {}
    sets = [s for s in args.sets.split(",") if s]
    for index, image_set in enumerate(sets):
        folder = args.work / f"eval_{image_set}"
        shutil.rmtree(folder, ignore_errors=True)
        command = [*CLI, "evaluate", str(run), "--methods", args.methods, "--device", args.device]
        command += ["--out", str(folder), "--quiet", *(["--validation"] if image_set == "validation" else [])]
        command += [a for s in args.evaluate_set for a in ("--set", s)]
        code, _ = loan.run(command, (loan.left_s() - args.pack_s) / (len(sets) - index))
        if (folder / "metrics.csv").is_file():
            evaluations[image_set] = folder
            record["evaluation"][image_set] = evaluation_table(folder / "metrics.csv", cfg)
        else:
            record["evaluation"][image_set] = f"no metrics.csv (exit code {code})"
    return evaluations


def loan_session(args) -> int:
    """The stages in order; a stage that fails is recorded (``errors``) and the later ones still run
    on what there is, so that whatever was trained comes back."""
    loan = Loan(args.out, args.work, args.budget_s)
    record: dict = {"budget_s": args.budget_s, "argv": sys.argv[1:], "errors": {}, "evaluation": {}}
    run = args.work / "run"

    def stage(name: str, action, *arguments):
        try:
            return action(*arguments)
        except Exception as exc:  # noqa: BLE001 - recorded; the later stages still run
            first_line = str(exc).splitlines()[0] if str(exc) else ""
            loan.say(f"{name} failed: {type(exc).__name__}: {first_line}")
            record["errors"][name] = f"{type(exc).__name__}: {exc}"
            return None

    record["machine"] = stage("machine", machine)
    if record["machine"]:
        m = record["machine"]
        loan.say(
            f"GPU: {m['gpu']}; torch {m['torch']} CUDA {m['cuda']}; CPU {m['cpu']} ({m['cpu_cores']} cores): "
            f"{m['instruction_sets']}"
        )
    shutil.rmtree(run, ignore_errors=True)
    stage("train", train_stage, loan, args, record, run)
    trained = (run / "checkpoints" / "last.pt").is_file()
    evaluations = (stage("evaluate", evaluate_stage, loan, args, record, run) if trained else None) or {}
    stage("results", results_archive, loan, run, evaluations)
    if trained:
        record["pack"] = stage("pack", pack, loan, run)
    else:
        record["pack"] = {"refused": ["no checkpoint: nothing trained"]}
    record["commands"] = loan.commands
    record["wall_s"] = time.monotonic() - loan.t0
    text = json.dumps(_finite(record), indent=1, default=str) + "\n"
    (loan.out / "record.json").write_text(text, encoding="utf-8")
    loan.say(f"record: {loan.out / 'record.json'}; OUT holds {sorted(p.name for p in loan.out.iterdir())}")
    return 1 if record["errors"] or not (record["pack"] or {}).get("manifest") else 0


def _peak_gib(output: str) -> float | None:
    match = re.search(r"peak GPU memory ([0-9.]+) GiB", output)
    return float(match.group(1)) if match else None


def _finite(value):
    """``value`` with every non-finite float as None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the loan's OUT folder (what comes back)")
    parser.add_argument("--budget-s", type=float, required=True, help="seconds this script may take, all stages")
    parser.add_argument("--config", default="paper", help="preset or YAML file of a new run (default paper)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="config override (resumed: the keys it may change)",
    )
    parser.add_argument("--no-loan-overrides", action="store_true", help="leave out LOAN_OVERRIDES")
    parser.add_argument("--resume", type=Path, metavar="PACK.pack.json", help="continue a packed run")
    parser.add_argument("--stop-after", type=int, metavar="N", help="end the training session after step N")
    parser.add_argument("--device", default="cuda", choices=("cuda", "cpu", "auto"))
    parser.add_argument("--sets", default="test,validation", help="image sets to score (test, validation; '' none)")
    parser.add_argument("--methods", default="doe+net", help="methods to score (edofproj evaluate --methods)")
    parser.add_argument("--evaluate-set", action="append", default=[], metavar="KEY=VALUE", help="evaluate --set")
    parser.add_argument("--reserve-s", type=float, default=150.0, help="seconds kept for scoring and packing")
    parser.add_argument("--pack-s", type=float, default=20.0, help="seconds kept for packing")
    parser.add_argument("--work", type=Path, default=Path(os.environ.get("WORK", "/tmp/edofproj-loan")))
    args = parser.parse_args(argv)
    if args.out.resolve() == args.work.resolve() or args.work.resolve().is_relative_to(args.out.resolve()):
        parser.error("--work must lie outside OUT (only OUT's files come back, and few of them)")
    return args


def main(argv=None) -> int:
    return loan_session(parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
