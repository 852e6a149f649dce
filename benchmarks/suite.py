"""The benchmark suite: named cases, one runner, one output format, comparable across commits.

    python benchmarks/suite.py [--cases a,b] [--repeats N] [--out results.json]
    python benchmarks/suite.py --list
    python benchmarks/suite.py compare BASE.json NEW.json      # or the .csv files

Each **case** measures one thing a user or the README quotes, with the library code the one-off scripts
of ``benchmarks/`` use (nothing is re-implemented here):

* ``training-step-1t``, ``training-step-2t``: one training step of the ``cpu`` preset (its session built
  as ``edofproj train`` builds it, the substitutions of ``bench_training.py`` for what a fresh clone
  lacks), on one and on two torch threads; wall and process-CPU milliseconds per step.
* ``shipped-600x800``, ``shipped-1080p``: the shipped method ``doe+net`` of ``builtin:cpu-doe-net`` per
  3-channel frame, through :meth:`Method.frame_function` (the object ``compensate`` and ``live`` call: the
  reference model's real-time network; a network with a linear base filter would run behind its display
  guard), with FFT Wiener (PyTorch, cached filter, 33x33 disk PSF, as
  ``edofproj bench``) in the same rounds, interleaved in a rotating order (``bench_realtime.py``'s
  ``interleaved_ms``), on 2 threads; the ratio is the median of the per-round ratios.
* ``live-loop``: the pipelined loop of ``edofproj live builtin:cpu-doe-net`` at 600x800 on the simulated
  devices of ``bench_live.py`` (in-memory display; a camera returning a ready virtual capture, then the
  virtual ProCams simulating every capture), one PyTorch/OpenCV thread per stage as ``bench_live.py``.

* ``export-1080p``: ``edofproj export builtin:cpu-doe-net --height 1080 --width 1920`` in a child process: its
  peak resident memory (``ru_maxrss`` of that child), CPU and wall seconds and the file's size.
* ``onnx-600x800-1t`` ... ``onnx-1080p-2t``: the shipped method per frame in PyTorch and in ONNX Runtime (the file
  ``export`` writes for the size), alternate frames in one process (``bench_onnx.py``), on 1 or 2 threads: the
  per-pair ratio ONNX Runtime / PyTorch of wall and of process-CPU time, and which way the guard decided the
  random frame; ``onnx-1080p-whole-2t`` with every frame decided on the whole frame (the file's ``If`` branch).

* ``compensate-1080p``: ``edofproj compensate builtin:cpu-doe-net --depth-mm 500`` on 1080x1920 frames in child
  processes: one frame (``--image``; the command also projects its result and scores it) with its wall, CPU and
  peak memory; one frame given a capture (``--capture``: the network alone, as on a rig) with its wall and CPU;
  a folder of 8 frames (``--images``) with the frames per second and the network's milliseconds per frame it
  prints; and ``python -c "import torch"``, the start-up both pay.

* ``demo``, ``demo-quick``: ``edofproj demo`` (``--quick``) into a temporary folder, the wall and CPU seconds of
  each of its stages (training, evaluation, timing, 3-D scene, textured surface, report; CPU: the process and its
  training processes), ``doe+net``'s mean and worst SSIM and, for the full demo, the largest difference of its
  scores from the README's results table. Run only when named (``--cases demo``: 8-15 minutes on 2 cores); for
  an AVX2-only CPU's figures on a wider one, set the limits of :mod:`edofproj.machine` in the environment.
  ``benchmarks/demo_later_stages.py`` times the stages after training on a finished demo's folder.

**Output.** One row per (case, metric): ``case, metric, value, unit, repeats, median, min, commit, date,
torch, threads, isa, load1`` where ``value`` is the median of ``repeats`` samples, ``commit`` the
checkout's ``git describe --always --dirty``, ``date`` UTC ISO 8601, ``isa`` the CPU's instruction sets
(:func:`edofproj.machine.instruction_sets`) and ``load1`` the one-minute load average when the case
started. ``--out results.json`` writes ``{"format": 1, "rows": [...]}`` and the same rows to
``results.csv`` beside it (atomically); the rows are printed as a table in any case.

**compare** prints per (case, metric) found in both files NEW's median / BASE's median (above 1: slower
for ``ms``, faster for ``frames/s``), the commits and instruction sets of each.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
FORMAT = 1
#: The columns of a result row, in order.
FIELDS = (
    "case", "metric", "value", "unit", "repeats", "median", "min",
    "commit", "date", "torch", "threads", "isa", "load1",
)  # fmt: skip
SHIPPED_RUN = "builtin:cpu-doe-net"


@dataclass
class Measurement:
    """Samples of one metric of a case (one per repeat, in ``unit``) and the threads it ran on;
    ``count``: the repeats behind a single figure (a throughput over ``count`` frames), else ``len(samples)``."""

    metric: str
    samples: list[float]
    unit: str
    threads: int
    count: int | None = None


@dataclass
class Context:
    """What a case runs with: samples per metric, the wall clock and the process-CPU clock (seconds)."""

    repeats: int
    clock: Callable[[], float] = time.perf_counter
    cpu_clock: Callable[[], float] = time.process_time


@dataclass
class Case:
    name: str
    description: str
    run: Callable[[Context], list[Measurement]]
    default_repeats: int
    #: run when no ``--cases`` are given (False: only when named, e.g. the minutes-long demo)
    by_default: bool = True


@dataclass
class Machine:
    """What every row names: the checkout, the date, torch, the CPU's instruction sets."""

    commit: str
    date: str
    torch: str
    isa: str
    load1: Callable[[], float] = field(default=lambda: os.getloadavg()[0])


def this_machine() -> Machine:
    import torch

    from edofproj.machine import instruction_sets

    try:
        commit = subprocess.run(
            ["git", "-C", str(HERE), "describe", "--always", "--dirty"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return Machine(
        commit=commit or "unknown",
        date=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        torch=torch.__version__,
        isa=instruction_sets(),
    )


def timed(function: Callable[[], object], ctx: Context, warmup: int = 1) -> tuple[list[float], list[float]]:
    """Wall and process-CPU milliseconds of ``ctx.repeats`` calls of ``function`` after ``warmup`` calls."""
    for _ in range(warmup):
        function()
    wall, cpu = [], []
    for _ in range(ctx.repeats):
        start, cpu_start = ctx.clock(), ctx.cpu_clock()
        function()
        wall.append(1e3 * (ctx.clock() - start))
        cpu.append(1e3 * (ctx.cpu_clock() - cpu_start))
    return wall, cpu


def _script(name: str):
    """A sibling script of ``benchmarks/`` as a module (its functions reused, its ``main`` not run)."""
    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    return __import__(name)


# ---- cases -------------------------------------------------------------------------------------------


def training_step(threads: int) -> Callable[[Context], list[Measurement]]:
    """One training step of the ``cpu`` preset on ``threads`` torch threads (module docstring)."""

    def run(ctx: Context) -> list[Measurement]:
        import warnings

        import torch

        from edofproj.config import load_config
        from edofproj.training.distributed import setup_process_group
        from edofproj.training.trainer import _Session

        bench_training = _script("bench_training")
        torch.set_num_threads(threads)
        warnings.simplefilter("ignore")
        extra, _ = bench_training.substitutions("cpu", [])
        cfg = load_config("cpu", extra)
        with tempfile.TemporaryDirectory() as tmp:
            session = _Session(cfg, Path(tmp) / "run", setup_process_group("cpu"))
            wall, cpu = timed(session.train_step, ctx, warmup=2)
        precision = bench_training.precision_that_runs(cfg)
        return [
            Measurement(f"step wall ({precision})", wall, "ms", threads),
            Measurement(f"step process CPU ({precision})", cpu, "ms", threads),
        ]

    return run


def shipped(height: int, width: int, threads: int = 2) -> Callable[[Context], list[Measurement]]:
    """The shipped ``doe+net`` per frame against FFT Wiener in the same rounds (module docstring)."""

    def run(ctx: Context) -> list[Measurement]:
        import torch

        from edofproj.evaluation import timing
        from edofproj.methods.builder import build_method

        torch.set_num_threads(threads)
        frame_function = _script("bench_shipped_methods").frame_function
        interleaved_ms = _script("bench_realtime").interleaved_ms
        method = build_method(SHIPPED_RUN, "doe+net")
        module = method.frame_function(None)  # what compensate and live call (a network behind its guard if it has one)
        module.to(memory_format=torch.channels_last)  # type: ignore[attr-defined]  (live's layout)
        frames = {
            "doe+net": frame_function(module, height, width),
            "fft-wiener": timing.wiener_torch_case(timing.disk_psf(33), 1e-3, "cpu").build(height, width),
        }
        times = interleaved_ms(frames, ctx.repeats, warmup=1)
        ratios = [n / w for n, w in zip(times["doe+net"], times["fft-wiener"], strict=True)]
        return [
            Measurement("doe+net (shipped, as compensate runs it)", times["doe+net"], "ms", threads),
            Measurement("FFT Wiener (PyTorch, cached filter)", times["fft-wiener"], "ms", threads),
            Measurement("doe+net / FFT Wiener", ratios, "ratio", threads),
        ]

    return run


def live_loop(height: int = 600, width: int = 800, threads: int = 1) -> Callable[[Context], list[Measurement]]:
    """The live loop of the shipped method on simulated devices (module docstring)."""

    def run(ctx: Context) -> list[Measurement]:
        import cv2
        import torch

        from edofproj.application.live import run_live
        from edofproj.methods.builder import build_method
        from edofproj.procams.devices.cameras import VirtualCamera
        from edofproj.procams.devices.displays import MemoryDisplay

        bench_live = _script("bench_live")
        torch.set_num_threads(threads)
        cv2.setNumThreads(threads)
        method = build_method(SHIPPED_RUN)
        net = method.frame_function(None)
        rig, calibration, target = bench_live.virtual_rig(method.design.cfg, height, width)
        display = MemoryDisplay()
        display.show(calibration.inverse_table.apply(torch.from_numpy(target)).numpy())
        camera = bench_live.InstantCamera(VirtualCamera(rig, display).grab_native())
        run_live(net, calibration, MemoryDisplay(), camera, [("warm-up", target)] * 2)
        instant = run_live(net, calibration, MemoryDisplay(), camera, [("target", target)] * ctx.repeats)
        display = MemoryDisplay()
        virtual = run_live(net, calibration, display, VirtualCamera(rig, display), [("target", target)] * ctx.repeats)
        return [
            Measurement("instant camera: frames/s", [instant.fps], "frames/s", threads, instant.frames),
            Measurement(
                "instant camera: compensate stage", [1e3 * s for s in instant.stage_s["compensate"]], "ms", threads
            ),
            Measurement("instant camera: latency", [1e3 * s for s in instant.latency_s], "ms", threads),
            Measurement("virtual ProCams: frames/s", [virtual.fps], "frames/s", threads, virtual.frames),
            Measurement("virtual ProCams: capture stage", [1e3 * s for s in virtual.stage_s["capture"]], "ms", threads),
            Measurement("virtual ProCams: latency", [1e3 * s for s in virtual.latency_s], "ms", threads),
        ]

    return run


#: The demo's stages, each begun by the first progress event (``start`` or ``note``) whose text starts so
#: (:func:`edofproj.application.demo.run_demo`'s announcements); a stage ends where the next one begins.
DEMO_STAGES = (
    ("training", "stage 1/4 training"),
    ("evaluation", "stage 2/4 evaluation"),
    ("timing", "stage 3/4 timing"),
    ("scene", "scene "),
    ("surface", "textured surface "),
    ("report", "stage 4/4 report"),
)
#: The README's results table: the demo's rows, and the largest difference it states between runs of the demo
#: on different CPUs (its text: "on the AMD EPYC by 0.0017").
README = HERE.parent / "README.md"
README_TOLERANCE = 0.0017


def tree_cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its children that have ended (the demo's training
    processes, once it has waited for them)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def demo_stage_seconds(
    events: Sequence[tuple[str, float, float]], end: tuple[float, float]
) -> dict[str, tuple[float, float]]:
    """``{stage: (wall s, CPU s)}`` of :data:`DEMO_STAGES` from the demo's progress ``events`` ``(text, wall,
    cpu)`` in order and the clocks at its ``end``; a stage the events never begin is left out, and ``total``
    spans the first stage's beginning to the end."""
    begins: list[tuple[str, float, float]] = []
    for stage, prefix in DEMO_STAGES:
        found = next(((wall, cpu) for text, wall, cpu in events if text.startswith(prefix)), None)
        if found is not None:
            begins.append((stage, *found))
    out = {}
    for (stage, wall, cpu), nxt in zip(begins, [*[(w, c) for _, w, c in begins[1:]], end]):
        out[stage] = (nxt[0] - wall, nxt[1] - cpu)
    if begins:
        out["total"] = (end[0] - begins[0][1], end[1] - begins[0][2])
    return out


def readme_demo_rows(text: str) -> dict[str, dict[str, float]]:
    """``{method: {column: value}}`` of the README's results table (between its ``demo-results`` markers):
    ``ssim`` (mean SSIM 300-800 mm), ``ssim_worst``, ``psnr``, ``psnr_worst``, ``de2000`` (mean CIEDE2000)."""
    start, end = text.index("--8<-- [start:demo-results]"), text.index("--8<-- [end:demo-results]")
    rows = {}
    for line in text[start:end].splitlines():
        cells = [c.strip().replace("*", "") for c in line.strip().strip("|").split("|")]
        if len(cells) != 7 or not cells[2][:1].isdigit():
            continue
        method = cells[0].split(" ")[0]
        values = [float(c.split(" ")[0]) for c in cells[2:]]
        rows[method] = dict(zip(("ssim", "ssim_worst", "psnr", "psnr_worst", "de2000"), values))
    return rows


def demo_table_differences(
    table, range_mm: tuple[float, float], readme: dict[str, dict[str, float]]
) -> dict[str, float]:
    """Largest absolute difference between a demo's scores (``table``: its
    :class:`~edofproj.evaluation.results.MetricsTable`) and the README's rows, per column group: ``ssim`` (mean
    and worst SSIM), ``psnr`` (dB), ``de2000``; over the methods in both (NaN where none is)."""
    lo, hi = range_mm
    worst = {"ssim": float("nan"), "psnr": float("nan"), "de2000": float("nan")}
    for method in set(readme) & set(table.methods()):
        ours = {}
        for metric in ("ssim", "psnr", "de2000"):
            stats = table.range_stats(method, metric, lo, hi)
            ours[metric], ours[f"{metric}_worst"] = stats.mean, stats.worst
        for column, value in readme[method].items():
            group = column.split("_")[0]
            difference = abs(ours[column] - value)
            worst[group] = difference if worst[group] != worst[group] else max(worst[group], difference)
    return worst


def demo(quick: bool = False) -> Callable[[Context], list[Measurement]]:
    """``edofproj demo`` (``--quick``) as a user runs it, into a temporary folder: the wall and CPU seconds of
    each stage (:data:`DEMO_STAGES`; CPU: this process and the training processes, :func:`tree_cpu_seconds`),
    ``doe+net``'s mean and worst SSIM over 300-800 mm and, for the full demo, the largest difference of
    its scores from the README's table (:func:`demo_table_differences`; the README states
    :data:`README_TOLERANCE`). The demo decides by the time it measures which optional baselines it trains:
    on a loaded machine its rows of those may be the shipped runs' instead (its report says which)."""

    def run(ctx: Context) -> list[Measurement]:
        from edofproj.application.demo import OURS, run_demo
        from edofproj.progress import StageProgress

        class Recorder(StageProgress):
            def __init__(self) -> None:
                super().__init__("demo", enabled=False)
                self.events: list[tuple[str, float, float]] = []

            def start(self, stage: str, total: float, later_s: float = 0.0, detail: str = "") -> None:
                self.events.append((stage, ctx.clock(), tree_cpu_seconds()))
                super().start(stage, total, later_s, detail)

            def note(self, message: str) -> None:
                self.events.append((message, ctx.clock(), tree_cpu_seconds()))
                super().note(message)

        stages: dict[str, list[float]] = {}
        quality: dict[str, list[float]] = {}
        for _ in range(ctx.repeats):
            recorder = Recorder()
            with tempfile.TemporaryDirectory() as tmp:
                result = run_demo(Path(tmp) / "demo", quick=quick, progress=recorder)
                end = (ctx.clock(), tree_cpu_seconds())
            for stage, (wall, cpu) in demo_stage_seconds(recorder.events, end).items():
                stages.setdefault(f"{stage} wall", []).append(wall)
                stages.setdefault(f"{stage} CPU (process tree)", []).append(cpu)
            table, range_mm = result.evaluation.table, result.evaluation.range_mm
            stats = table.range_stats(OURS, "ssim", *range_mm)
            quality.setdefault(f"{OURS} mean SSIM", []).append(stats.mean)
            quality.setdefault(f"{OURS} worst SSIM", []).append(stats.worst)
            if not quick:
                readme = readme_demo_rows(README.read_text(encoding="utf-8"))
                for group, difference in demo_table_differences(table, range_mm, readme).items():
                    quality.setdefault(f"largest |difference| from the README table: {group}", []).append(difference)
        return [Measurement(metric, samples, "s", 2) for metric, samples in stages.items()] + [
            Measurement(metric, samples, "score", 2) for metric, samples in quality.items()
        ]

    return run


def _child_run(command: list[str], log: Path, ctx: Context) -> tuple[float, float, float, str]:
    """Run ``command`` as a child process, its output to the file ``log`` (no pipe to fill), and return its
    wall seconds, CPU seconds (user + system) and peak resident memory in GB (the child's own ``ru_maxrss``,
    from ``os.wait4``) and what it printed; a failure raises with the end of what it printed."""
    start = ctx.clock()
    with open(log, "w") as out:
        child = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
    wall = ctx.clock() - start
    printed = log.read_text()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"edofproj {' '.join(command[3:5])} failed: {printed.strip()[-300:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1e6, printed  # ru_maxrss in kB


def export_memory(height: int = 1080, width: int = 1920) -> Callable[[Context], list[Measurement]]:
    """``edofproj export builtin:cpu-doe-net --height H --width W`` in a child process, once per repeat: its
    peak resident memory (the child's own ``ru_maxrss``, from ``os.wait4``), CPU and wall seconds, the file."""

    def run(ctx: Context) -> list[Measurement]:
        peaks, cpus, walls, sizes = [], [], [], []
        for _ in range(ctx.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "net.onnx"
                command = [sys.executable, "-m", "edofproj.cli", "export", SHIPPED_RUN, "--out", str(out)]
                command += ["--height", str(height), "--width", str(width)]
                wall, cpu, peak, _ = _child_run(command, Path(tmp) / "log", ctx)
                walls.append(wall)
                cpus.append(cpu)
                peaks.append(peak)
                sizes.append(out.stat().st_size / 1e6)
        return [
            Measurement("export peak RSS", peaks, "GB", 2),
            Measurement("export file", sizes, "MB", 2),
            Measurement("export process CPU", cpus, "s", 2),
            Measurement("export wall", walls, "s", 2),
        ]

    return run


def textured_frame(height: int, width: int, seed: int = 0):
    """A ``(3, height, width)`` float32 test frame in [0, 1]: 48-px checks under 8-px random colour blocks."""
    import numpy as np
    import torch

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width]
    texture = rng.random((3, height // 8 + 1, width // 8 + 1)).repeat(8, axis=1).repeat(8, axis=2)[:, :height, :width]
    checks = ((yy // 48 + xx // 48) % 2).astype(float)
    return torch.from_numpy(np.clip(0.15 + 0.5 * checks + 0.3 * texture, 0.0, 1.0)).float()


def synthetic_psf_map_lab(folder: Path, height: int = 1140, width: int = 912) -> tuple[Path, Path]:
    """A PSF map of a ``height x width`` projector on dots every 12 px with widths like a measured V-groove's
    (minor 0.7-1.6 px, major 1.3-5 px, growing away from the centre column; the angle turning down the image)
    and a target with edges and texture, written to ``folder``: ``(map.npz, target.png)``."""
    import numpy as np

    from edofproj.imaging.image_io import write_image
    from edofproj.procams.psf_map import PSFMap, covariance

    xs, ys = np.arange(0.0, width, 12.0), np.arange(0.0, height, 12.0)
    t = np.abs(xs - width / 2) / (width / 2)
    cov = np.array([[covariance(1.3 + 3.7 * u**2, 0.7 + 0.9 * u, 1.2 * y / height - 0.6) for u in t] for y in ys])
    psf_map = PSFMap(xs=xs, ys=ys, cov=cov, offset_px=np.zeros(2), fitted=np.ones(cov.shape[:2], bool),
                     projector_hw=(height, width))  # fmt: skip
    psf_map.save(folder / "map.npz")
    write_image(folder / "target.png", textured_frame(height, width), bits=8)
    return folder / "map.npz", folder / "target.png"


def compensate_psf_map(height: int = 1140, width: int = 912) -> Callable[[Context], list[Measurement]]:
    """``edofproj compensate --psf-map MAP --image TARGET --method cls`` on :func:`synthetic_psf_map_lab`'s
    files in a child process, once per repeat: its wall and CPU (user + system) seconds, peak memory and the
    objective it reached (printed: ``objective A -> B``)."""

    def run(ctx: Context) -> list[Measurement]:
        import re

        walls, cpus, peaks, objectives = [], [], [], []
        with tempfile.TemporaryDirectory() as tmp:
            psf_map, target = synthetic_psf_map_lab(Path(tmp), height, width)
            for _ in range(ctx.repeats):
                command = [sys.executable, "-m", "edofproj.cli", "compensate", "--psf-map", str(psf_map)]
                command += ["--image", str(target), "--method", "cls", "--out", str(Path(tmp) / "out.png")]
                wall, cpu, peak, printed = _child_run(command, Path(tmp) / "log", ctx)
                walls.append(wall)
                cpus.append(cpu)
                peaks.append(peak)
                found = re.search(r"objective \S+ -> (\S+) in", printed)
                objectives.append(float(found.group(1)) if found else float("nan"))
        return [
            Measurement("compensate --psf-map cls wall", walls, "s", 2),
            Measurement("compensate --psf-map cls CPU (user + system)", cpus, "s", 2),
            Measurement("compensate --psf-map cls peak RSS", peaks, "GB", 2),
            Measurement("compensate --psf-map cls final objective", objectives, "objective", 2),
        ]

    return run


def compensate_command(
    height: int = 1080, width: int = 1920, frames: int = 8
) -> Callable[[Context], list[Measurement]]:
    """``edofproj compensate builtin:cpu-doe-net`` on ``height x width`` frames for a flat screen at 500 mm, in child
    processes, once per repeat: one frame (``--image``, which also projects the result and scores it: wall, CPU,
    peak memory), one frame given a capture (``--capture``: the network alone, as on a projector-camera rig;
    wall, CPU), ``frames`` frames (``--images DIR``: the frames per second and the network's milliseconds per
    frame it prints) and, for the start-up both pay, ``python -c "import torch"`` (wall)."""

    def run(ctx: Context) -> list[Measurement]:
        import re

        from edofproj.imaging.image_io import write_image

        one, cpus, peaks, rates, network_ms, imports = [], [], [], [], [], []
        from_capture, from_capture_cpu = [], []
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "frames"
            folder.mkdir()
            for i in range(frames):
                write_image(folder / f"frame{i:02d}.png", textured_frame(height, width, seed=i))
            for _ in range(ctx.repeats):
                command = [sys.executable, "-m", "edofproj.cli", "compensate", SHIPPED_RUN, "--depth-mm", "500"]
                wall, cpu, peak, _ = _child_run(
                    [*command, "--image", str(folder / "frame00.png"), "--out", str(Path(tmp) / "one.png")],
                    Path(tmp) / "log",
                    ctx,
                )
                one.append(wall)
                cpus.append(cpu)
                peaks.append(peak)
                given_capture = [*command[:5], "--image", str(folder / "frame00.png")]  # no --depth-mm
                given_capture += ["--capture", str(folder / "frame01.png"), "--out", str(Path(tmp) / "capture.png")]
                wall, cpu, _, _ = _child_run(given_capture, Path(tmp) / "log", ctx)
                from_capture.append(wall)
                from_capture_cpu.append(cpu)
                out = Path(tmp) / f"out{len(one)}"
                _, _, _, printed = _child_run(
                    [*command, "--images", str(folder), "--out", str(out)], Path(tmp) / "log", ctx
                )
                found = re.search(r"([\d.]+) frames/s \(network ([\d.]+) ms per frame", printed)
                rates.append(float(found.group(1)) if found else float("nan"))
                network_ms.append(float(found.group(2)) if found else float("nan"))
                imports.append(_child_run([sys.executable, "-c", "import torch"], Path(tmp) / "log", ctx)[0])
        return [
            Measurement("one frame: command wall", one, "s", 2),
            Measurement("one frame: command CPU (user + system)", cpus, "s", 2),
            Measurement("one frame: command peak RSS", peaks, "GB", 2),
            Measurement("one frame from a capture: command wall", from_capture, "s", 2),
            Measurement("one frame from a capture: command CPU (user + system)", from_capture_cpu, "s", 2),
            Measurement(f"{frames} frames: frames/s", rates, "frames/s", 2),
            Measurement(f"{frames} frames: network per frame", network_ms, "ms", 2),
            Measurement("python -c 'import torch' wall", imports, "s", 2),
        ]

    return run


_EXPORTED: dict[tuple, Path] = {}


def onnx_vs_torch(
    height: int, width: int, threads: int, whole_frame: bool = False
) -> Callable[[Context], list[Measurement]]:
    """The shipped ``doe+net`` of :data:`SHIPPED_RUN` (its network, behind its guard where it has one) per frame
    in PyTorch and in ONNX Runtime (its file as ``edofproj export`` writes it for the frame size, once per
    process), alternate frames in one process (``bench_onnx.py``'s ``interleaved_ms``), on ``threads`` threads.
    ``whole_frame``: the guard's band set to cover every margin, so that each frame is decided on the whole
    frame (a frame too close to call; the ONNX file's ``If`` branch), else the random frame's own decision
    (``branch`` 1: the whole frame); a shipped network without a guard has no such case (no rows)."""

    def run(ctx: Context) -> list[Measurement]:
        import torch

        from edofproj.compensation.export import export_network
        from edofproj.evaluation import timing
        from edofproj.methods import guard
        from edofproj.methods.builder import build_method

        bench_onnx = _script("bench_onnx")
        torch.set_num_threads(threads)
        module = build_method(SHIPPED_RUN, "doe+net").module
        assert module is not None
        net = module.eval()
        guarded = isinstance(net, guard.GuardedNetwork)
        if whole_frame and not guarded:
            return []
        band = guard.GUARD_MARGIN_BAND
        if whole_frame:
            guard.GUARD_MARGIN_BAND = float("inf")
        try:
            key = (height, width, whole_frame)
            if key not in _EXPORTED:
                folder = Path(tempfile.mkdtemp(prefix="suite-onnx-"))
                _EXPORTED[key] = folder / f"shipped-{height}x{width}.onnx"
                export_network(net, _EXPORTED[key], "onnx", height, width)
            frame = [timing._random_frame(height, width, "cpu", seed) for seed in (0, 1)]  # the cases' frame
            took_branch = None
            if guarded:
                with torch.inference_mode():
                    took_branch = float(bool(net.export_parts(height, width)[0](*frame)[3]))
            torch_frame = timing.network_torch_case(net, "doe+net").build(height, width)
            onnx_frame = timing.network_onnx_case(str(_EXPORTED[key]), "doe+net", "cpu", threads).build(height, width)
            (onnx_ms, onnx_cpu), (torch_ms, torch_cpu) = bench_onnx.interleaved_ms(
                onnx_frame, torch_frame, ctx.repeats, 1
            )
        finally:
            guard.GUARD_MARGIN_BAND = band
        return [
            Measurement("ONNX Runtime / PyTorch, wall", [o / t for o, t in zip(onnx_ms, torch_ms)], "ratio", threads),
            Measurement(
                "ONNX Runtime / PyTorch, process CPU", [o / t for o, t in zip(onnx_cpu, torch_cpu)], "ratio", threads
            ),
            Measurement("PyTorch wall", torch_ms, "ms", threads),
            Measurement("ONNX Runtime wall", onnx_ms, "ms", threads),
            Measurement("PyTorch process CPU", torch_cpu, "ms", threads),
            Measurement("ONNX Runtime process CPU", onnx_cpu, "ms", threads),
        ] + (
            []
            if took_branch is None
            else [Measurement("decided on the whole frame (1) or its tiles (0)", [took_branch], "flag", threads)]
        )

    return run


CASES: dict[str, Case] = {
    case.name: case
    for case in (
        Case("training-step-1t", "one step of the cpu preset, 1 thread", training_step(1), 10),
        Case("training-step-2t", "one step of the cpu preset, 2 threads", training_step(2), 10),
        Case("shipped-600x800", "shipped doe+net and FFT Wiener per 600x800 frame, 2 threads", shipped(600, 800), 10),
        Case("shipped-1080p", "shipped doe+net and FFT Wiener per 1080x1920 frame, 2 threads", shipped(1080, 1920), 3),
        Case("live-loop", "live loop of the shipped method at 600x800, simulated devices", live_loop(), 6),
        Case(
            "export-1080p",
            "edofproj export of the shipped method at 1080x1920: peak memory, file",
            export_memory(),
            1,
            False,
        ),
        Case(
            "onnx-600x800-1t",
            "shipped doe+net per 600x800 frame, ONNX Runtime / PyTorch, 1 thread",
            onnx_vs_torch(600, 800, 1),
            6,
        ),
        Case(
            "onnx-600x800-2t",
            "shipped doe+net per 600x800 frame, ONNX Runtime / PyTorch, 2 threads",
            onnx_vs_torch(600, 800, 2),
            6,
        ),
        Case(
            "onnx-1080p-1t",
            "shipped doe+net per 1080x1920 frame, ONNX Runtime / PyTorch, 1 thread",
            onnx_vs_torch(1080, 1920, 1),
            3,
            False,
        ),
        Case(
            "onnx-1080p-2t",
            "shipped doe+net per 1080x1920 frame, ONNX Runtime / PyTorch, 2 threads",
            onnx_vs_torch(1080, 1920, 2),
            3,
            False,
        ),
        Case(
            "onnx-1080p-whole-2t",
            "as onnx-1080p-2t, every frame decided on the whole frame",
            onnx_vs_torch(1080, 1920, 2, True),
            3,
            False,
        ),
        Case(
            "compensate-psf-map-cls",
            "edofproj compensate --psf-map --method cls, 1140x912, synthetic map (V-groove-like widths), child process",
            compensate_psf_map(),
            2,
        ),
        Case(
            "compensate-1080p",
            "edofproj compensate of the shipped method at 1080x1920: one frame, a folder of 8, child processes",
            compensate_command(),
            2,
            False,
        ),
        Case("demo-quick", "edofproj demo --quick: seconds per stage (about a minute)", demo(quick=True), 1),
        Case("demo", "edofproj demo: seconds per stage, scores against the README (8-15 minutes)", demo(), 1, False),
    )
}


# ---- runner and format -------------------------------------------------------------------------------


def rows_of(case: str, measurements: Sequence[Measurement], machine: Machine, load1: float) -> list[dict]:
    """One result row (:data:`FIELDS`) per measurement."""
    rows = []
    for m in measurements:
        if not m.samples:
            continue
        median = float(statistics.median(m.samples))
        rows.append(
            {
                "case": case,
                "metric": m.metric,
                "value": median,
                "unit": m.unit,
                "repeats": m.count or len(m.samples),
                "median": median,
                "min": float(min(m.samples)),
                "commit": machine.commit,
                "date": machine.date,
                "torch": machine.torch,
                "threads": m.threads,
                "isa": machine.isa,
                "load1": round(float(load1), 2),
            }
        )
    return rows


def run_cases(
    names: Sequence[str],
    repeats: int | None,
    machine: Machine,
    cases: dict[str, Case] = CASES,
    ctx_clocks: dict | None = None,
) -> list[dict]:
    """Run each named case (``repeats`` samples, or the case's default) and return its rows."""
    rows: list[dict] = []
    for name in names:
        case = cases[name]
        ctx = Context(repeats=repeats or case.default_repeats, **(ctx_clocks or {}))
        load1 = machine.load1()
        rows += rows_of(name, case.run(ctx), machine, load1)
    return rows


def csv_text(rows: Sequence[dict]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


def write_results(path: Path, rows: Sequence[dict]) -> Path:
    """``path`` (JSON) and the same rows as CSV beside it; returns the CSV's path."""
    from edofproj.fileio import write_text_atomic

    csv_path = path.with_suffix(".csv")
    write_text_atomic(path, json.dumps({"format": FORMAT, "rows": list(rows)}, indent=1) + "\n")
    write_text_atomic(csv_path, csv_text(rows))
    return csv_path


def read_results(path: Path) -> list[dict]:
    """The rows of a results file, JSON or CSV (numbers as floats); a one-line error if unreadable."""
    from edofproj.errors import EdofprojError

    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise EdofprojError(f"cannot read '{path}': {exc.strerror or exc}") from None
    try:
        if path.suffix == ".csv":
            rows = list(csv.DictReader(io.StringIO(text)))
        else:
            rows = json.loads(text)["rows"]
        for row in rows:
            row["median"] = float(row["median"])
            row["case"], row["metric"], row["unit"] = str(row["case"]), str(row["metric"]), str(row["unit"])
    except (ValueError, KeyError, TypeError) as exc:
        raise EdofprojError(
            f"'{path}' is not a results file of benchmarks/suite.py ({type(exc).__name__}: {exc})"
        ) from None
    return rows


def compare_rows(base: Sequence[dict], new: Sequence[dict]) -> list[tuple[str, str, str, float, float, float]]:
    """``(case, metric, unit, base median, new median, new / base)`` for each (case, metric) in both, in NEW's order."""
    index = {(r["case"], r["metric"]): r for r in base}
    out = []
    for row in new:
        old = index.get((row["case"], row["metric"]))
        if old is None:
            continue
        ratio = row["median"] / old["median"] if old["median"] else float("nan")
        out.append((row["case"], row["metric"], row["unit"], old["median"], row["median"], ratio))
    return out


def format_table(rows: Sequence[dict]) -> str:
    lines = [
        "| case | metric | median | min | unit | repeats | threads |",
        "| --- | --- | ---: | ---: | --- | ---: | ---: |",
    ]
    lines += [
        f"| {r['case']} | {r['metric']} | {r['median']:.4g} | {r['min']:.4g} | {r['unit']} | {r['repeats']} | {r['threads']} |"
        for r in rows
    ]
    return "\n".join(lines)


def _header(rows: Sequence[dict]) -> str:
    if not rows:
        return "(no rows)"
    commits = sorted({str(r["commit"]) for r in rows})
    isas = sorted({str(r["isa"]) for r in rows})
    return f"commit {', '.join(commits)}; torch {rows[0]['torch']}; CPU {' | '.join(isas)}"


def compare_main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(prog="suite.py compare", description="NEW / BASE per case and metric")
    parser.add_argument("base", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args(argv)
    base, new = read_results(args.base), read_results(args.new)
    print(f"base: {args.base}: {_header(base)}")
    print(f"new:  {args.new}: {_header(new)}")
    print("| case | metric | unit | base | new | new / base |")
    print("| --- | --- | --- | ---: | ---: | ---: |")
    pairs = compare_rows(base, new)
    for case, metric, unit, old, now, ratio in pairs:
        print(f"| {case} | {metric} | {unit} | {old:.4g} | {now:.4g} | {ratio:.3f} |")
    if not pairs:
        print("(no case and metric in both files)")
    return 0


def run_main(argv: Sequence[str]) -> int:
    from edofproj.errors import EdofprojError

    parser = argparse.ArgumentParser(prog="suite.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cases",
        default=None,
        help="comma-separated case names (default: all but "
        + ", ".join(name for name, case in CASES.items() if not case.by_default)
        + ")",
    )
    parser.add_argument("--repeats", type=int, default=None, help="samples per metric (default: each case's own)")
    parser.add_argument("--out", type=Path, default=None, help="results JSON (the CSV is written beside it)")
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    args = parser.parse_args(argv)
    if args.list:
        for case in CASES.values():
            print(f"{case.name:18s} {case.description} (default repeats {case.default_repeats})")
        return 0
    default = [name for name, case in CASES.items() if case.by_default]
    names = default if args.cases is None else [n.strip() for n in args.cases.split(",") if n.strip()]
    unknown = [n for n in names if n not in CASES]
    if unknown or not names:
        raise EdofprojError(
            f"--cases: unknown case(s) {', '.join(unknown) or '(none given)'}; the cases: {', '.join(CASES)}"
        )
    if args.repeats is not None and args.repeats < 1:
        raise EdofprojError(f"--repeats must be at least 1, not {args.repeats}")
    if args.out is not None and (args.out.suffix != ".json" or not args.out.parent.is_dir()):
        raise EdofprojError(f"--out '{args.out}': a .json file in an existing folder")
    machine = this_machine()
    print(
        f"suite: {', '.join(names)}; {_header([{'commit': machine.commit, 'isa': machine.isa, 'torch': machine.torch}])}"
    )
    rows = run_cases(names, args.repeats, machine)
    print(format_table(rows))
    if args.out is not None:
        csv_path = write_results(args.out, rows)
        print(f"wrote {args.out} and {csv_path}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    from edofproj.errors import EdofprojError

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["compare"]:
            return compare_main(argv[1:])
        return run_main(argv)
    except EdofprojError as exc:
        print(f"suite.py: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
