"""Training several runs side by side within a time budget (one-thread ``edofproj train`` processes).

On a small CPU, two one-thread training processes finish more work than one two-thread process
(measured on the 2-core development machine), so runs are trained as ``workers`` parallel subprocesses
``python -m edofproj.cli train --config PRESET --out RUN --set train.threads=1 ...``.

Jobs are started in order. *Required* jobs always run. An *optional* job starts only when it
is predicted to end before ``deadline``:

    now + setup_s + steps * rate * relative_cost  <=  max(deadline, end of the required jobs)

where ``rate`` is the measured seconds per step of a reference job (the first required job
with ``relative_cost == 1``, once it has logged :data:`RATE_STEPS` steps; before that ``default_rate_s``: the demo
gives the ``lens+net`` step of its network on the 2-core development machine), and
``relative_cost``/``setup_s`` are the job's measured cost per step relative to the reference
and its one-off start-up cost (process start, PSF tables). The end of the required jobs is predicted
the same way: an optional job that ends before it runs on a worker that would otherwise wait for them,
and costs no time even when the whole demo overruns its budget. A job that cannot fit is skipped
with a note. ``deadline`` is the end of training that leaves ``later_s`` for the stages after it on a
machine of ``default_rate_s``; those stages run on the same CPU, so once the rate is measured they are
predicted to take ``later_s * rate / default_rate_s`` (:meth:`ParallelTrainer.speed`) and the deadline
moves by the difference (:meth:`ParallelTrainer.training_deadline`). ``on_measured`` is called once, when
the rate is first measured.

:meth:`ParallelTrainer.plan` decides before any training which optional jobs fit, simulating the
worker slots with the predicted times (the rule above, applied when a slot frees), and says which
will not be trained; the loop applies the same rule again with the measured rate when each job is
due to start. Progress is read from each run's ``train_log.csv`` and counted in *work*: steps
weighted by each job's ``relative_cost`` (a step of a job 8.5 times as costly counts 8.5 times), over
the jobs planned -- so the percentage follows the predicted time and does not jump when a job is
left out.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from ..errors import EdofprojError
from ..progress import StageProgress, format_duration

POLL_S = 1.0
#: Steps the reference job logs before its seconds per step are taken as the machine's rate (all of them
#: when it has fewer): its first steps include the warm-up. In five demos on a 2-core AMD EPYC, whose
#: ``lens+net`` runs averaged 0.187-0.220 s a step, the rate after 3 steps ranged over 0.157-0.251 s, after 50
#: over 0.157-0.210 s (docs/experiments/2026-11-28-demo-later-stages.md).
RATE_STEPS = 50
#: The note of an optional job planned beyond the deadline because it ends before the required jobs.
WAITING_WORKER_NOTE = (
    "trained beyond the time budget on a worker that waits for the required runs: predicted to end before them"
)


@dataclass
class TrainingJob:
    """One run to train: ``method`` it serves, its directory, config overrides and cost model."""

    method: str
    run_dir: Path
    overrides: list[str]
    steps: int
    required: bool = True
    relative_cost: float = 1.0
    setup_s: float = 15.0
    status: str = "pending"  # pending, running, done, failed, skipped
    note: str = ""
    process: subprocess.Popen | None = None
    started: float = 0.0
    ended: float = 0.0

    def steps_done(self) -> int:
        """Rows in the run's ``train_log.csv`` (one per optimizer step)."""
        log = self.run_dir / "train_log.csv"
        try:
            with log.open("rb") as handle:
                return max(sum(1 for _ in handle) - 1, 0)
        except OSError:
            return 0

    def training_seconds(self) -> float:
        """Seconds of training logged by the run (last row's ``seconds``)."""
        try:
            lines = (self.run_dir / "train_log.csv").read_text(encoding="utf-8").strip().splitlines()
            return float(lines[-1].split(",")[-1]) if len(lines) > 1 else 0.0
        except (OSError, ValueError, IndexError):
            return 0.0


def train_command(config: str, job: TrainingJob) -> list[str]:
    """The argument list of the job's training process: ``python -m edofproj.cli train --config CONFIG
    --out RUN_DIR --quiet --set train.threads=1`` followed by ``--set`` of each of the job's overrides (later
    ones win; they set the run's steps where it differs from CONFIG's), run with this interpreter."""
    sets = [item for override in ["train.threads=1"] + list(job.overrides) for item in ("--set", override)]
    return [
        sys.executable,
        "-m",
        "edofproj.cli",
        "train",
        "--config",
        config,
        "--out",
        str(job.run_dir),
        "--quiet",
    ] + sets


class ParallelTrainer:
    """Runs :class:`TrainingJob` s as ``workers`` parallel processes before ``deadline`` (module docstring)."""

    def __init__(
        self,
        jobs: Sequence[TrainingJob],
        config: str,
        log_dir: Path,
        workers: int,
        deadline: float,
        progress: StageProgress,
        default_rate_s: float = 0.1,
        later_s: float = 0.0,
        on_measured: Callable[["ParallelTrainer"], None] | None = None,
        on_idle_worker: Callable[[], None] | None = None,
    ) -> None:
        self.jobs = list(jobs)
        self.config = config
        self.log_dir = Path(log_dir)
        self.workers = max(int(workers), 1)
        self.deadline = deadline
        self.progress = progress
        self.default_rate_s = default_rate_s
        self.later_s = later_s
        self.on_measured = on_measured
        #: called once, the first time a worker slot is free with no job left to start while others still run
        #: (it must return at once: e.g. start a thread that does later work on the free core)
        self.on_idle_worker = on_idle_worker
        self.calibrated = False
        #: predicted seconds from the last :meth:`plan` until the last job it keeps ends
        self.planned_seconds = 0.0

    # -- cost model ------------------------------------------------------------------------
    def measured_rate_s(self) -> float | None:
        """Seconds per step of the reference job once it has logged :data:`RATE_STEPS` steps (or all of its
        steps, when it has fewer; module docstring), else None."""
        for job in self.jobs:
            if job.required and job.relative_cost == 1.0 and job.status in ("running", "done"):
                steps = job.steps_done()
                if steps >= min(RATE_STEPS, job.steps):
                    return job.training_seconds() / steps
        return None

    def reference_rate_s(self) -> float:
        """:meth:`measured_rate_s`, or ``default_rate_s`` before it is measured."""
        measured = self.measured_rate_s()
        return self.default_rate_s if measured is None else measured

    def measured(self) -> bool:
        """Whether the reference job's rate is measured (:meth:`measured_rate_s`)."""
        return self.measured_rate_s() is not None

    def speed(self) -> float:
        """This machine's seconds per step relative to the default's: ``reference_rate_s / default_rate_s``
        (1 until measured)."""
        return self.reference_rate_s() / self.default_rate_s if self.default_rate_s > 0 else 1.0

    def later_seconds(self) -> float:
        """Predicted seconds of the stages after training on this machine: ``later_s * speed``."""
        return self.later_s * self.speed()

    def training_deadline(self) -> float:
        """``deadline`` moved by the later stages' predicted change on this machine:
        ``deadline - later_s * (speed - 1)``."""
        return self.deadline - self.later_s * (self.speed() - 1.0)

    def predicted_seconds(self, job: TrainingJob) -> float:
        """Predicted wall time (s) of the whole job: ``setup_s + steps * rate * relative_cost``, with ``rate``
        the :meth:`reference_rate_s`."""
        return job.setup_s + job.steps * self.reference_rate_s() * job.relative_cost

    def remaining_seconds(self, job: TrainingJob) -> float:
        """Predicted seconds until ``job`` ends: :meth:`predicted_seconds` while pending, 0 once done, failed
        or skipped. While running, ``(steps - done) * rate`` with the job's own measured seconds per step
        once it has logged 3 steps (else the reference rate times its relative cost), plus what is left of
        ``setup_s`` while it has logged no step."""
        if job.status == "pending":
            return self.predicted_seconds(job)
        if job.status != "running":
            return 0.0
        done = job.steps_done()
        rate = job.training_seconds() / done if done >= 3 else self.reference_rate_s() * job.relative_cost
        start_up = max(job.setup_s - (time.perf_counter() - job.started), 0.0) if done == 0 else 0.0
        return start_up + (job.steps - done) * rate

    # -- processes -------------------------------------------------------------------------
    def start(self, job: TrainingJob) -> None:
        """Start the job's training process (:func:`train_command`; one OpenMP/MKL thread), its output going
        to ``log_dir/<run name>.log``, and mark it running."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = (self.log_dir / f"{job.run_dir.name}.log").open("w", encoding="utf-8")
        env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        job.process = subprocess.Popen(train_command(self.config, job), stdout=log, stderr=subprocess.STDOUT, env=env)
        log.close()
        job.status, job.started = "running", time.perf_counter()

    def poll(self, job: TrainingJob) -> None:
        """Update a started job's status from its process: unchanged while it runs, ``done`` on exit code 0,
        else ``failed`` with a note quoting the log's last line. A failed *required* job stops every
        process and raises :class:`~edofproj.errors.EdofprojError` naming its log; a failed optional job
        does not stop the others. Raises ``RuntimeError`` if the job was never started."""
        if job.process is None:
            raise RuntimeError(f"{job.run_dir.name}: polled before its training process was started")
        code = job.process.poll()
        if code is None:
            return
        job.ended = time.perf_counter()
        if code == 0:
            job.status = "done"
            return
        job.status = "failed"
        job.note = f"training failed (exit {code}): {self.last_log_line(job)}"
        if job.required:
            self.stop_all()
            raise EdofprojError(
                f"training the {job.method} run failed: {self.last_log_line(job)} "
                f"(log: {self.log_dir / (job.run_dir.name + '.log')})"
            )

    def last_log_line(self, job: TrainingJob) -> str:
        """The last non-blank line of the job's process log (stripped); ``"no log"`` if the log cannot be
        read, ``"no output"`` if it is empty."""
        try:
            lines = [
                line
                for line in (self.log_dir / f"{job.run_dir.name}.log")
                .read_text(encoding="utf-8", errors="replace")
                .splitlines()
                if line.strip()
            ]
        except OSError:
            return "no log"
        return lines[-1].strip() if lines else "no output"

    def stop_all(self) -> None:
        """Terminate the training processes this trainer started (by their process ids)."""
        for job in self.jobs:
            if job.process is not None and job.process.poll() is None:
                job.process.terminate()
                try:
                    job.process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    job.process.kill()
                job.status, job.note = "failed", "stopped"

    # -- the plan ----------------------------------------------------------------------------
    def _slots_after_running(self) -> list[float]:
        """Predicted seconds until each worker slot is free, from the running jobs."""
        slots = sorted(self.remaining_seconds(j) for j in self.jobs if j.status == "running")
        return slots + [0.0] * (self.workers - len(slots))

    def required_end(self) -> float:
        """Predicted time (``time.perf_counter``) at which the running and pending required jobs have all
        ended, simulating the worker slots with the current estimates."""
        slots = sorted(self.remaining_seconds(j) for j in self.jobs if j.status == "running" and j.required)
        slots += [0.0] * (self.workers - len(slots))
        for job in self.jobs:
            if job.status == "pending" and job.required:
                slots.sort()
                slots[0] += self.predicted_seconds(job)
        return time.perf_counter() + max(slots)

    def plan(self) -> list[TrainingJob]:
        """Decide which pending optional jobs fit, before they are due to start: each pending job starts
        when the first worker slot frees (in order), and an optional one that would then end after both the
        deadline and the end of the required jobs (:meth:`required_end`) is skipped with a note (shown at
        once). Returns the skipped jobs and keeps the predicted seconds until the last planned job ends,
        :attr:`planned_seconds`. :meth:`run` calls it first; calling it again re-plans with the current
        estimates."""
        now = time.perf_counter()
        slots = self._slots_after_running()
        deadline = self.training_deadline()
        limit = max(deadline, self.required_end())
        skipped = []
        for job in self.jobs:
            if job.status != "pending":
                continue
            slots.sort()
            predicted = self.predicted_seconds(job)
            if job.required or now + slots[0] + predicted <= limit:
                if not job.required and now + slots[0] + predicted > deadline:
                    job.note = WAITING_WORKER_NOTE
                elif job.note == WAITING_WORKER_NOTE:  # re-planned within the budget
                    job.note = ""
                slots[0] += predicted
                continue
            self.skip(job, predicted)
            skipped.append(job)
        self.planned_seconds = max(slots)
        return skipped

    def skip(self, job: TrainingJob, predicted: float) -> None:
        """Mark ``job`` skipped with a note saying why, shown at once."""
        job.status = "skipped"
        job.note = (
            f"not trained: predicted {format_duration(predicted, unit=True)} for {job.steps} steps "
            f"would end after the time budget"
        )
        self.progress.note(f"{job.method}: {job.note}")

    @staticmethod
    def work(job: TrainingJob, steps: int) -> float:
        """Progress units of ``steps`` steps of ``job``: ``steps * relative_cost`` (module docstring)."""
        return min(steps, job.steps) * job.relative_cost

    def total_work(self) -> float:
        """Work of the jobs planned (pending, running or done)."""
        return sum(self.work(j, j.steps) for j in self.jobs if j.status in ("running", "done", "pending"))

    # -- the loop ----------------------------------------------------------------------------
    def next_job(self) -> TrainingJob | None:
        """The next pending job that may start now; optional jobs that cannot fit (before the deadline or the
        end of the required jobs) are skipped."""
        for job in self.jobs:
            if job.status != "pending":
                continue
            if job.required:
                return job
            predicted = self.predicted_seconds(job)
            if time.perf_counter() + predicted <= max(self.training_deadline(), self.required_end()):
                return job
            self.skip(job, predicted)
        return None

    def calibrate(self) -> bool:
        """The first time the rate is :meth:`measured`: plan the optional jobs again with it (:meth:`plan`) and
        call ``on_measured``. Returns whether it did so now."""
        if self.calibrated or not self.measured():
            return False
        self.calibrated = True
        self.plan()
        if self.on_measured is not None:
            self.on_measured(self)
        return True

    def run(self) -> list[TrainingJob]:
        """Train the jobs: :meth:`plan` them, then keep up to ``workers`` processes running (starting the
        next job that :meth:`next_job` allows), poll them every ``POLL_S`` seconds, :meth:`calibrate` and
        report progress, until no job runs or may start; the first time a worker is left without a job while
        others run, call ``on_idle_worker``. Returns the jobs with their final status and notes. On any
        exception (a failed required job, Ctrl-C) the processes are stopped and the exception re-raised."""
        self.plan()
        try:
            while True:
                running = [j for j in self.jobs if j.status == "running"]
                while len(running) < self.workers:
                    job = self.next_job()
                    if job is None:
                        break
                    self.start(job)
                    running.append(job)
                if not running:
                    break
                if len(running) < self.workers and self.on_idle_worker is not None:
                    idle, self.on_idle_worker = self.on_idle_worker, None
                    idle()
                time.sleep(POLL_S)
                for job in running:
                    self.poll(job)
                self.calibrate()
                self.report()
        except BaseException:
            self.stop_all()
            raise
        return self.jobs

    def report(self) -> None:
        """Update the progress display: the work done of the work of the pending, running and done jobs
        (:meth:`work`), each running or done job's ``method done/steps`` as detail, and :meth:`eta_s` as the
        stage's ETA."""
        done = sum(self.work(j, j.steps_done()) for j in self.jobs if j.status in ("running", "done"))
        total = self.total_work()
        detail = ", ".join(
            f"{j.method} {min(j.steps_done(), j.steps)}/{j.steps}" for j in self.jobs if j.status in ("running", "done")
        )
        eta = self.eta_s()
        self.progress.later_s = self.later_seconds()
        self.progress.set(done, detail=detail, total=max(total, 1), eta_s=eta)

    def eta_s(self) -> float:
        """Time until the last job ends, simulating the worker slots with the current estimates
        (optional jobs that would end after the deadline and the required jobs are left out: they will be
        skipped)."""
        now = time.perf_counter()
        slots = self._slots_after_running()
        limit = max(self.training_deadline(), self.required_end())
        for job in self.jobs:
            if job.status == "pending":
                slots.sort()
                predicted = self.predicted_seconds(job)
                if job.required or now + slots[0] + predicted <= limit:
                    slots[0] += predicted
        return max(slots) if slots else 0.0
