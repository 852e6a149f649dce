"""The demo: train our method and its baselines on built-in data, evaluate, and write the report.

Stages (each shown with its ETA by :class:`~edofproj.progress.StageProgress`):

1. **training** -- the runs of :func:`demo_jobs`, two one-thread processes at a time
   (:mod:`.schedule`): ``doe_net`` (the ``cpu`` preset: the DOE with a U-Net jointly, then a fresh U-Net
   for the DOE found, :mod:`edofproj.training.phases`; ``cpu-realtime``: the real-time multi-rate network,
   one phase) and ``lens_net`` (the same network without a DOE) always; ``axicon_net``, ``cubic_net`` (the
   same network with the classic elements of the preset) and
   ``lens_onlineprodeb`` when they are predicted to fit the time budget (planned before any training,
   :meth:`~.schedule.ParallelTrainer.plan`, and printed in one line, :func:`plan_line`). Each run trains
   its preset's recipe: a fixed element's network is trained exactly as ``doe_net``'s final network (the
   refit phase alone), so that the comparison measures the optics; ``lens_onlineprodeb``, another
   architecture, its own recipe (:data:`OWN_RECIPE_STEPS`). A baseline that does not fit is taken from the run the package ships for it
   (:data:`BUILTIN_BASELINES`: the same preset and steps, trained beforehand), and the report says
   which runs were trained here and which were shipped; ``retrain_baselines`` trains them all. Once a
   worker has no run left to train while another still trains, the cubic plate's PSFs for the evaluation are
   simulated on the core it leaves free (:class:`DesignPrefetch`);
2. **evaluation** -- :func:`~edofproj.evaluation.pipeline.evaluate_run` of ``doe_net`` with the
   others as baselines, on the held-out built-in photographs: the evaluation's default methods
   (:func:`demo_methods`), the classic elements' linear baselines (``X+wiener``, ``X+ensemble``) among them,
   their cost predicted with the rest before any training (:func:`evaluation_seconds`);
3. **timing** -- milliseconds per compensated frame (:mod:`edofproj.evaluation.timing`), and one scene,
   :data:`DEMO_SCENE` (a sphere in front of a wall: a depth edge), scored on the first held-out
   image at the panel size (:mod:`edofproj.evaluation.scenes`; the quick demo scores only
   ``lens``, ``doe`` and ``doe+net`` there, the full one every method but the classic linear
   baselines), and one textured surface, :data:`DEMO_SURFACE`, with the photometric variants of the
   blind methods (:mod:`edofproj.evaluation.surfaces`);
4. **report** -- ``report.html`` (self-contained), ``report.md`` + ``figures/``, ``summary.md``,
   ``metrics.csv``, with the paper's claims (:mod:`edofproj.reporting.claims`) measured on the held-out images.

``--quick`` shrinks everything (few steps, small crops, two small test images, three depths)
into a smoke run of about a minute; its numbers are not meant to be judged. Its DOE trains for too
few steps to leave the flat plate it starts as, and its report says so (:func:`flat_doe_note`).
"""

from __future__ import annotations

import dataclasses
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..builtin_runs import BUILTIN_RUNS, PREFIX
from ..config import STATEMENT_KEYS, apply_overrides, load_config, to_dict, unread_doe_keys
from ..errors import EdofprojError
from ..evaluation import timing
from ..evaluation.pipeline import Evaluation, design_depths_m, evaluate_run, is_evaluation_key
from ..evaluation.scenes import evaluate_scenes
from ..evaluation.surfaces import evaluate_surfaces
from ..fileio import read_arrays
from ..methods.builder import MethodBuilder, PreparedMethod, require_trained_run
from ..methods.catalogue import CLASSIC_ELEMENTS, OURS, method_spec, select_methods
from ..methods.designs import DEPTH_KEY_RESOLUTION_M, OpticalDesign
from ..progress import StageProgress, format_duration
from ..reporting.claims import Claim, ssim_claims, wall_time_claim
from ..reporting.document import Figure, Heading, Paragraph, Table
from ..reporting.scenes import scene_summary_table, write_scene_report
from ..reporting.surfaces import surface_summary_table, write_surface_report
from ..reporting.tables import format_text_table, range_table
from ..reporting.writeup import claims_section, psf_figure_depths_m, write_documents
from ..runs import DOE_NAME, load_run, saved_config, write_run_config
from ..runs.directory import flatten_keys
from ..training.end_to_end import resolve_mixed_precision
from ..training.phases import JOINT, run_key, total_steps, training_phases
from .durations import FULL_BUDGET_MIN, QUICK_BUDGET_MIN
from .schedule import ParallelTrainer, TrainingJob

OURS_RUN_DIR = "doe_net"
#: The textured surface the demo's report adds (:mod:`edofproj.data.textures`; not a training texture) and its
#: ambient light (a fraction of the projector's white).
DEMO_SURFACE = "brick"
DEMO_AMBIENT = 0.05
#: The scene the demo's report adds (:mod:`edofproj.scenes.builtin`).
DEMO_SCENE = "sphere_wall"
QUICK_SCENE_METHODS = ("lens", "doe", OURS)
LOG_DIR = "logs"


@dataclass(frozen=True)
class DemoSettings:
    """Budget and sizes of a demo. ``overrides`` apply to every run (training and evaluation keys)."""

    name: str
    budget_s: float
    overrides: tuple[str, ...]
    evaluation_estimate_s: float
    timing_sizes: tuple[tuple[int, int], ...]
    timing_repeats: int
    cubic_table_depths: int
    #: the most steps of a refit phase (``train.refit_steps``) of the runs that have one (None: the preset's)
    max_refit_steps: int | None = None
    #: evaluation seconds of each classic linear baseline (``X+wiener``, ``X+ensemble``) beyond
    #: ``evaluation_estimate_s``, their cubic PSFs apart (:func:`evaluation_seconds`)
    linear_method_s: float = 0.0
    #: methods of the default set that this demo does not evaluate
    left_out: tuple[str, ...] = ()


#: Seconds of the full demo's stages after training (evaluation, scenes, surfaces; the timing apart,
#: :data:`TIMING_ESTIMATE_S`) for the methods scored by default before the classic elements' linear baselines
#: joined them (a shipped ``cubic+net`` and its 2-D PSFs included), on a machine whose ``lens+net`` step takes
#: :data:`LENS_NET_STEP_S`; on another the plan scales them by the measured step
#: (:meth:`~edofproj.application.schedule.ParallelTrainer.speed`, the step over the first
#: :data:`~edofproj.application.schedule.RATE_STEPS`). Calibrated on 2026-11-28 on a 2-core AMD EPYC with AVX2
#: only, where the default demo's stages after training took 308 s up to the report (``lens+net`` 0.183 s a
#: step over its first 50, 1.76 times the assumed) and 322 s in a run before the timing stage's budget (0.197 s):
#: with these constants and the report's margin the plan predicts 317 and 340 s
#: (docs/experiments/2026-11-28-demo-later-stages.md). Before the evaluation ran its tasks on every core they
#: took 453 s there and 218 s on the Intel Xeon limited to AVX2 (0.107 s a step), which bound the prediction
#: from above (docs/experiments/2026-11-28-amd-epyc-demo.md).
EVALUATION_ESTIMATE_S = 71.0
#: The stages' cost after the training of ``net.architecture``'s networks relative to the U-Net's (whose demo
#: :data:`EVALUATION_ESTIMATE_S` is), at the assumed step of each (:data:`LENS_NET_STEP_S`): on the AMD EPYC of
#: :data:`EVALUATION_ESTIMATE_S` the multi-rate networks' demo (``--config cpu-realtime``) spent 399 s after
#: training at 0.105 s a ``lens+net`` step (1.7 times the assumed), the U-Net demo 453 s at 0.209 s (2.0 times):
#: the evaluation does not shrink with the network's step (docs/experiments/2026-11-28-amd-epyc-demo.md; both
#: measured before the evaluation ran on every core).
EVALUATION_COST_BY_NETWORK = {"unet": 1.0, "multirate": 1.2}
#: Seconds each classic linear baseline adds to the full demo's evaluation: measured, the four of the
#: axicon and the multifocal zones (radial PSFs included) added 23 s of CPU time to ``evaluate
#: builtin:cpu-doe-unet`` (one thread; 39 s of wall time on the loaded 2-core machine); 3 s each with the
#: calibration of :data:`EVALUATION_ESTIMATE_S` (the evaluation on every core).
LINEAR_METHOD_SECONDS = 3.0

#: Steps of the baselines of another architecture, trained in one phase by their own recipe (those of their
#: shipped runs) unless the demo's settings or the user set ``train.steps``: ``lens+onlineprodeb``, at 9 to 53
#: times the U-Net's cost per step (:func:`job_costs`).
OWN_RECIPE_STEPS = {"lens+onlineprodeb": 1800}
#: Training crops of the baselines of ``demo --pretrained`` (its run's last network, as the shipped runs of its
#: recipe were trained): 2,400 steps of batch 4, or 600 of batch 16 (:func:`pretrained_baseline_overrides`).
PRETRAINED_BASELINE_CROPS = 9600

FULL = DemoSettings(
    name="full",
    budget_s=FULL_BUDGET_MIN * 60,
    overrides=("train.checkpoint_every=100",),
    evaluation_estimate_s=EVALUATION_ESTIMATE_S,
    timing_sizes=((256, 256), (600, 800)),
    timing_repeats=3,
    cubic_table_depths=24,
    linear_method_s=LINEAR_METHOD_SECONDS,
)
QUICK = DemoSettings(
    name="quick",
    budget_s=QUICK_BUDGET_MIN * 60,
    overrides=(
        "train.steps=12",
        "train.batch_size=2",
        "data.crop=64",
        "train.checkpoint_every=12",
        "train.psf_table_depths=16",
        "evaluation.image_size=[96,128]",
        "data.max_test_images=2",
        "evaluation.depths_mm=[300,500,800]",
        "evaluation.cls_iterations=30",
        "evaluation.wiener_tuning_images=4",
        "evaluation.wiener_tuning_depths=3",
        "imaging.depth_layers=4",
    ),
    evaluation_estimate_s=35.0,
    timing_sizes=((128, 128),),
    timing_repeats=2,
    cubic_table_depths=8,
    max_refit_steps=12,
    # measured: the four linear baselines of the axicon and the multifocal zones added 7.5 s of CPU time
    # to a quick-sized evaluate of builtin:cpu-doe-unet (one thread; 14 s of wall time, loaded machine)
    linear_method_s=2.0,
    # the depth-ensemble filter alone needs the cubic plate at 32 depths of the slow 2-D engine (over a minute)
    left_out=("cubic+wiener", "cubic+ensemble"),
)

#: Seconds per training step of ``lens+net`` (the network alone: its PSFs come from a precomputed table),
#: by the network the runs train (``net.architecture``, at its preset's widths: the ``cpu`` preset's U-Net
#: 8-16-32-64, the ``cpu-realtime`` preset's multi-rate network) and the arithmetic it trains in (``bf16``:
#: autocast where the CPU computes bfloat16 natively; ``none``: float32), and of OnlineProDeb, by arithmetic;
#: one thread of the 2-core development machine (``benchmarks/bench_training.py --stages --threads 1``,
#: float32 with the AVX2 limits; the U-Net's 2026-11-28). The plan uses them before any run has logged a step;
#: then the measured ``lens+net`` rate replaces them (:mod:`.schedule`).
LENS_NET_STEP_S = {
    ("unet", "bf16"): 0.090,
    ("unet", "none"): 0.104,
    ("multirate", "bf16"): 0.058,
    ("multirate", "none"): 0.063,
}
ONLINEPRODEB_STEP_S = {"bf16": 0.83, "none": 3.36}
#: Seconds per step of simulating ``doe+net``'s PSFs (its DOE moves: they are simulated every step; the
#: others read a table), by ``psf.precision`` and the arithmetic key of :data:`LENS_NET_STEP_S` (``bf16``
#: stands for a CPU with native bfloat16, whose AVX-512 also computes the PSFs faster): the PSF stage of
#: ``bench_training.py --stages --threads 1``, 2026-11-28 (``none``: the AVX2 limits). ``doe+net``'s step
#: is ``lens+net``'s plus this; the classic elements' ``X+net`` cost as much as ``lens+net``. One-off
#: start-up seconds of every run (process start, PSF tables); the cubic plate needs the 2-D engine for
#: its table, about 2.3 s per simulated depth (:data:`CUBIC_SECONDS_PER_DEPTH`).
DOE_PSF_STEP_S = {
    ("float64", "bf16"): 0.018,
    ("float64", "none"): 0.024,
    ("float32", "bf16"): 0.009,
    ("float32", "none"): 0.013,
}
SETUP_S = 15.0


#: The batch of the steps of :data:`LENS_NET_STEP_S` (the presets'): a phase of another ``train.batch_size``
#: (``train.refit_batch_size``) is assumed to cost in proportion.
STEP_BATCH = 4


def job_costs(cfg) -> dict[str, tuple[float, float]]:
    """Each trained method's cost per step relative to ``lens+net`` and its start-up seconds, for the
    networks and arithmetic of ``cfg`` (a network not listed: the U-Net's figures) and its PSFs'
    precision. ``lens+net`` (and the classic elements' ``X+net``) trains the network of the run's last phase
    (``refit_net`` where the config has one); a step of ``doe+net``'s joint phase costs its own network's
    step plus :data:`DOE_PSF_STEP_S`, one of its refit phase as much as ``lens+net``'s (its cost is their
    mean over its steps)."""
    precision = _precision_key(cfg)
    lens_step_s = reference_rate_s(cfg)
    onlineprodeb = ONLINEPRODEB_STEP_S[precision] / lens_step_s
    psf_s = DOE_PSF_STEP_S[(cfg.psf.precision, precision)]
    doe_net_s = sum(
        p.cfg.train.steps * (_step_s(p.cfg, precision) + (psf_s if p.name == JOINT else 0.0))
        for p in training_phases(cfg)
    )
    doe_net = doe_net_s / (total_steps(cfg) * lens_step_s)
    costs = {"doe+net": doe_net, "lens+onlineprodeb": onlineprodeb}
    costs.update({method: 1.0 for method in ("lens+net", "axicon+net", "cubic+net")})
    return {method: (cost, SETUP_S) for method, cost in costs.items()}


def reference_rate_s(cfg) -> float:
    """Seconds per ``lens+net`` step the plan assumes before measuring (:data:`LENS_NET_STEP_S`): a step of
    the run's last phase (its network and batch)."""
    return _step_s(training_phases(cfg)[-1].cfg, _precision_key(cfg))


def _step_s(phase_cfg, precision: str) -> float:
    """Assumed seconds of one step of the network of ``phase_cfg`` (a phase's configuration) at its batch."""
    architecture = _architecture_key(phase_cfg.net)
    return LENS_NET_STEP_S[(architecture, precision)] * phase_cfg.train.batch_size / STEP_BATCH


def _architecture_key(net) -> str:
    return net.architecture if (net.architecture, "none") in LENS_NET_STEP_S else "unet"


def _precision_key(cfg) -> str:
    precision = resolve_mixed_precision(cfg.train.mixed_precision, torch.device("cpu"))
    return "bf16" if precision == "bf16" else "none"


def _cost_key(cfg) -> tuple[str, str]:
    """The architecture of the network ``lens+net`` trains (the run's last phase's) and the arithmetic key."""
    return _architecture_key(cfg.final_network()), _precision_key(cfg)


#: The runs the package ships for a baseline (``builtin:NAME``), trained beforehand with the demo's
#: settings and a recipe (the ``cpu`` preset's U-Net in its refit phase, ``demo-refit-*``; the reference
#: model's real-time network in 600 steps of batch 16 of its refit phase, for ``demo --pretrained``; the
#: ``cpu-realtime`` preset's multi-rate network); the demo uses the one whose recipe is its own when training
#: the baseline would overrun the budget. Only runs present in :data:`~edofproj.builtin_runs.BUILTIN_RUNS` are used.
BUILTIN_BASELINES: dict[str, tuple[str, ...]] = {
    "axicon+net": ("demo-refit-axicon-net", "demo-axicon-net", "demo-realtime-axicon-net"),
    "cubic+net": ("demo-refit-cubic-net", "demo-cubic-net", "demo-realtime-cubic-net"),
    "lens+onlineprodeb": ("demo-lens-onlineprodeb", "demo-realtime-lens-onlineprodeb"),
}
CUBIC_SECONDS_PER_DEPTH = 2.3
#: Optional baselines in the order they are tried.
OPTIONAL_ORDER = ("axicon+net", "cubic+net", "lens+onlineprodeb")
#: Seconds of the demo's timing stage on the machine of :data:`LENS_NET_STEP_S` (24 s on the AMD EPYC of
#: :data:`EVALUATION_ESTIMATE_S`, at 1.76 times its step, with :data:`TIMING_CASE_BUDGET_S`).
TIMING_ESTIMATE_S = {"full": 14.0, "quick": 5.0}
#: Seconds of timed frames after which a case of the timing stage stops repeating (after its warm-up frame):
#: OnlineProDeb's network takes about 10 s a 600x800 frame on 2 AVX2 cores, timed once instead of
#: :attr:`DemoSettings.timing_repeats` times (``edofproj bench`` repeats every case).
TIMING_CASE_BUDGET_S = 5.0
REPORT_MARGIN_S = 15.0


def design_evaluation_depths_m(cfg, methods: Sequence[str], design: str) -> np.ndarray:
    """The distinct depths (m) at which the evaluation of ``methods`` and its report simulate ``design`` (a
    :attr:`~edofproj.methods.catalogue.MethodSpec.design`): the union of its methods' depths
    (:func:`~edofproj.evaluation.pipeline.design_depths_m`) and the PSF figure's
    (:func:`~edofproj.reporting.writeup.psf_figure_depths_m`); none without a method of it."""
    compensations = {method_spec(m).compensation for m in methods if method_spec(m).design == design}
    if not compensations:
        return np.zeros(0)
    depths_m = np.concatenate([design_depths_m(cfg, compensations), psf_figure_depths_m(cfg)])
    return np.unique(np.round(depths_m / DEPTH_KEY_RESOLUTION_M)) * DEPTH_KEY_RESOLUTION_M


class DesignPrefetch:
    """The cubic plate's PSFs (the slow 2-D engine: about 1-2 s a depth on one core) simulated on a thread while a
    training worker waits for the others, at the depths the evaluation will ask for
    (:func:`design_evaluation_depths_m`), one depth at a time, with one torch thread.

    :meth:`start` begins (``ours_run``'s ``config.yaml``: the configuration the evaluation opens; nothing is
    done when it is absent or no evaluated method uses the plate); :meth:`finish` stops it after the depth at
    hand (training is over: the evaluation then simulates the remaining depths itself, on every core), restores
    torch's threads and returns the design for :func:`~edofproj.evaluation.pipeline.evaluate_run`'s
    ``designs``, which takes it only if it was built with the evaluation's own configuration
    (:meth:`~edofproj.methods.builder.MethodBuilder.adopt`). A PSF does not depend on the threads that
    computed it nor on the depths simulated with it, so the scores are those of an evaluation that simulates
    every depth itself."""

    KIND = "cubic"

    def __init__(self, ours_run: Path, methods: Sequence[str]) -> None:
        self.ours_run = Path(ours_run)
        self.methods = list(methods)
        self.design: OpticalDesign | None = None
        self.simulated = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._threads = torch.get_num_threads()

    def start(self) -> None:
        if self._thread is not None or not (self.ours_run / "config.yaml").is_file():
            return
        cfg = saved_config(self.ours_run)
        depths_m = design_evaluation_depths_m(cfg, self.methods, self.KIND)
        if not len(depths_m):
            return
        self._threads = torch.get_num_threads()
        self._thread = threading.Thread(target=self._simulate, args=(cfg, depths_m), daemon=True)
        self._thread.start()

    def _simulate(self, cfg, depths_m: np.ndarray) -> None:
        torch.set_num_threads(1)  # the free core only: the other still trains
        try:
            design = MethodBuilder(None, cfg, self.ours_run.parent, explicit=False).classic_design(self.KIND)
            for depth_m in depths_m:
                if self._stop.is_set():
                    break
                design.psf([depth_m])
                self.simulated += 1
            self.design = design
        except EdofprojError:  # e.g. a sampling the plate refuses: the evaluation meets it and says so
            self.design = None

    def finish(self) -> list[OpticalDesign]:
        if self._thread is None:
            return []
        self._stop.set()
        self._thread.join()
        torch.set_num_threads(self._threads)
        return [self.design] if self.design is not None else []


def cubic_evaluation_depths(cfg, methods: Sequence[str]) -> int:
    """Depths at which the evaluation of ``methods`` and its report simulate the cubic plate (the slow 2-D
    engine): the cubic methods share one design (:class:`~edofproj.methods.builder.MethodBuilder`), simulated
    at the union of their depths (:func:`~edofproj.evaluation.pipeline.design_depths_m`) and the PSF
    figure's (:func:`~edofproj.reporting.writeup.psf_figure_depths_m`); 0 without a cubic method."""
    return len(design_evaluation_depths_m(cfg, methods, "cubic"))


def evaluation_seconds(settings: DemoSettings, cfg, methods: Sequence[str]) -> float:
    """Predicted seconds of the demo's evaluation of ``methods``: :attr:`DemoSettings.evaluation_estimate_s`
    (with ``cubic+net``'s 2-D PSFs) scaled for the network ``cfg`` trains (:data:`EVALUATION_COST_BY_NETWORK`),
    :attr:`DemoSettings.linear_method_s` for each classic linear baseline,
    and :data:`CUBIC_SECONDS_PER_DEPTH` for each depth at which the cubic plate's linear baselines
    simulate it beyond those of ``cubic+net`` (:func:`cubic_evaluation_depths`)."""
    linear = [m for m in methods if method_spec(m).optics in CLASSIC_ELEMENTS]
    networks = EVALUATION_COST_BY_NETWORK.get(cfg.final_network().architecture, 1.0)
    seconds = settings.evaluation_estimate_s * networks + settings.linear_method_s * len(linear)
    if any(method_spec(m).design == "cubic" for m in linear):
        extra = cubic_evaluation_depths(cfg, [*linear, "cubic+net"]) - cubic_evaluation_depths(cfg, ["cubic+net"])
        seconds += CUBIC_SECONDS_PER_DEPTH * extra
    return seconds


def demo_methods(settings: DemoSettings, methods: Sequence[str] | None) -> list[str]:
    """The methods a demo evaluates (those of a separate run only when it is trained or shipped):
    ``methods``, or the evaluation's default set (:func:`~edofproj.methods.catalogue.select_methods`) less
    :attr:`DemoSettings.left_out`."""
    if methods:
        return list(methods)
    return [spec.name for spec in select_methods(None) if spec.name not in settings.left_out]


def sets_steps(overrides: Sequence[str]) -> bool:
    """Whether ``overrides`` set ``train.steps``."""
    return any(o.split("=", 1)[0].strip() == "train.steps" for o in overrides)


def demo_jobs(
    out: Path,
    settings: DemoSettings,
    cfg,
    methods: Sequence[str] | None,
    user_overrides: Sequence[str],
    train_ours: bool = True,
    retrain_baselines: bool = False,
    steps_set: bool | None = None,
) -> list[TrainingJob]:
    """The training runs of a demo: ours (unless ``train_ours`` is false: a pretrained run stands for
    it) and lens+net required, the others optional (or required when named in ``methods`` or with
    ``retrain_baselines``). ``cfg`` is the demo's configuration (its settings' and the user's overrides
    applied); each run trains it with its method's :attr:`~edofproj.methods.catalogue.MethodSpec.train_overrides`
    for all its phases (:func:`~edofproj.training.phases.total_steps`: a fixed element's network trains the
    refit phase alone), those of :data:`OWN_RECIPE_STEPS` their own steps unless the settings or the user set
    ``train.steps`` (``steps_set``; None: found in their overrides); :attr:`DemoSettings.max_refit_steps` caps a
    refit phase. The cubic plate's cost includes its
    PSF table (its evaluation's 2-D PSFs are the evaluation's, :func:`evaluation_seconds`)."""
    if steps_set is None:
        steps_set = sets_steps([*settings.overrides, *user_overrides])
    common = list(settings.overrides) + list(user_overrides)
    wanted = set(methods) if methods else None
    jobs = []

    def add(method: str, run_dir: str, extra: list[str], required: bool, setup_extra: float = 0.0) -> None:
        if method in OWN_RECIPE_STEPS and not steps_set:
            extra.append(f"train.steps={OWN_RECIPE_STEPS[method]}")
        run_cfg = apply_overrides(cfg, extra)
        if settings.max_refit_steps is not None and run_cfg.train.refit_steps > settings.max_refit_steps:
            # the recipe's warm-up fraction of the shortened phase (a warm-up longer than its phase is refused)
            warmup = run_cfg.train.refit_warmup_steps * settings.max_refit_steps // run_cfg.train.refit_steps
            extra += [f"train.refit_steps={settings.max_refit_steps}", f"train.refit_warmup_steps={warmup}"]
            run_cfg = apply_overrides(cfg, extra)
        steps = total_steps(run_cfg)
        cost, setup = job_costs(run_cfg)[method]
        jobs.append(TrainingJob(method, out / run_dir, common + extra, steps, required, cost, setup + setup_extra))

    if train_ours:
        add(OURS, OURS_RUN_DIR, [], True)
    baseline_methods = ["lens+net"] + list(OPTIONAL_ORDER)
    for method in baseline_methods:
        spec = method_spec(method)
        if wanted is not None and method not in wanted:
            continue
        required = method == "lens+net" or wanted is not None or retrain_baselines
        extra = list(spec.train_overrides)
        setup_extra = 0.0
        if method == "cubic+net":
            extra.append(f"train.psf_table_depths={settings.cubic_table_depths}")
            setup_extra = CUBIC_SECONDS_PER_DEPTH * settings.cubic_table_depths
        if spec.run_dir is None:
            raise EdofprojError(f"method {method} has no separate run to train")
        add(method, spec.run_dir, extra, required, setup_extra)
    return jobs


def steps_sentence(jobs: Sequence[TrainingJob]) -> str:
    """The training steps of the demo's runs, grouped by count in the jobs' order: ``2400 training steps for
    doe+net, lens+net, axicon+net, cubic+net; 1800 for lens+onlineprodeb``."""
    groups: dict[int, list[str]] = {}
    for job in jobs:
        groups.setdefault(job.steps, []).append(job.method)
    parts = [
        f"{steps}{' training steps' if index == 0 else ''} for {', '.join(names)}"
        for index, (steps, names) in enumerate(groups.items())
    ]
    return "; ".join(parts)


def phases_sentence(jobs: Sequence[TrainingJob], training_config: str) -> str:
    """A clause on ``doe+net``'s two phases when its job (trained with ``training_config`` and the job's
    overrides) has them (else empty): the steps of each, and that the fixed elements' networks train the
    second alone."""
    ours = [job for job in jobs if job.method == OURS]
    if not ours:
        return ""
    phases = training_phases(load_config(training_config, ours[0].overrides))
    if len(phases) < 2:
        return ""
    joint, refit = phases
    return (
        f" ({OURS} in two phases: {joint.cfg.train.steps} steps of the DOE with a network, then "
        f"{refit.cfg.train.steps} of a fresh network for the DOE found, frozen; the baselines of that network "
        "train the second phase alone)"
    )


def plan_line(jobs: Sequence[TrainingJob]) -> str:
    """The training plan in one line: the runs trained here and those taken from shipped runs or
    left out (each with why, in its job's note)."""
    trained = [f"{j.method} ({j.steps} steps)" for j in jobs if j.status == "pending"]
    parts = [f"plan: trains {', '.join(trained)}" if trained else "plan: trains nothing"]
    shipped = [j.method for j in jobs if j.status == "built-in"]
    if shipped:
        parts.append(f"takes {', '.join(shipped)} from the shipped runs (predicted not to fit the time budget)")
    left_out = [j.method for j in jobs if j.status == "skipped"]
    if left_out:
        parts.append(f"leaves out {', '.join(left_out)} (predicted not to fit, no shipped run of its recipe)")
    return "; ".join(parts)


#: The preset of the demo that fits its budget on a CPU without native bfloat16: the ``cpu`` preset with the
#: real-time multi-rate network (``edofproj/presets/cpu-realtime.yaml``).
REALTIME_PRESET = "cpu-realtime"


def prediction_note(predicted_s: float, budget_s: float, rate_s: float, cfg) -> str:
    """The demo's predicted wall time once this machine's ``lens+net`` step (``rate_s`` seconds) is measured:
    :func:`overrun_note` when beyond ``budget_s``, else the prediction within the budget."""
    measured = f" (a lens+net step takes {rate_s:.3f} s here)"
    overrun = overrun_note(predicted_s, budget_s, cfg, measured)
    if overrun is not None:
        return overrun
    return (
        f"predicted {format_duration(predicted_s, unit=True)} in all{measured}, within the "
        f"{format_duration(budget_s, unit=True)} budget"
    )


def overrun_note(predicted_s: float, budget_s: float, cfg, measured: str = "") -> str | None:
    """One line when the demo is predicted to take longer than ``budget_s`` (None otherwise): the prediction
    (followed by ``measured``, what it rests on), the arithmetic the network trains in on this CPU and, for a
    U-Net in float32, the preset of the real-time network (:data:`REALTIME_PRESET`) with its cost per step
    relative to the U-Net's (:data:`LENS_NET_STEP_S`)."""
    if predicted_s <= budget_s:
        return None
    architecture, precision = _cost_key(cfg)
    arithmetic = "bfloat16" if precision == "bf16" else "float32 (no native bfloat16 here)"
    note = (
        f"predicted {format_duration(predicted_s, unit=True)} in all{measured}, beyond the "
        f"{format_duration(budget_s, unit=True)} budget: the network trains in {arithmetic}"
    )
    if architecture == "unet" and precision != "bf16":
        share = LENS_NET_STEP_S[("multirate", precision)] / LENS_NET_STEP_S[("unet", precision)]
        note += (
            f"; --config {REALTIME_PRESET} trains the real-time multi-rate network instead, at about {share:.0%} of "
            "the U-Net's step cost here (it scores lower: the documentation's Results page)"
        )
    return note


def jobs_table(jobs: Sequence[TrainingJob], pretrained: "PretrainedOurs | None" = None) -> Table:
    rows = []
    if pretrained is not None:
        rows.append(
            [
                OURS,
                OURS_RUN_DIR,
                f"{pretrained.steps}/{pretrained.steps}",
                "-",
                "pretrained",
                f"copied from {pretrained.source}",
            ]
        )
    for job in jobs:
        # a shipped run keeps every 10th log row: its steps are the job's, trained beforehand
        done = job.steps if job.status == "built-in" else job.steps_done()
        seconds = job.training_seconds()
        rows.append(
            [
                job.method,
                job.run_dir.name,
                f"{min(done, job.steps)}/{job.steps}",
                f"{seconds:.0f}" if done else "-",
                job.status,
                job.note,
            ]
        )
    return Table(
        ["method", "run", "steps", "training s", "status", "note"],
        rows,
        "Training runs (two one-thread processes in parallel)",
    )


#: Config keys that do not change what a run learns (bookkeeping, threads, evaluation settings): a
#: shipped baseline may differ from the demo's recipe in these only.
#: Keys that do not change what a run learns: naming, evaluation, bookkeeping, and statements about the
#: configuration (:data:`edofproj.config.STATEMENT_KEYS`).
RECIPE_IGNORED = ("name", "evaluation.", "imaging.", "data.max_test_images", "train.checkpoint_every",
                  "train.keep_checkpoints", "train.threads", "train.device", *STATEMENT_KEYS)  # fmt: skip
#: Keys a phase of training never reads (:func:`~edofproj.training.phases.refit_config` has copied what the
#: refit phase reads of them into its ``net`` and ``train`` keys).
PHASE_UNREAD = ("refit_net", "train.refit_")


def recipe_difference(shipped, expected) -> str | None:
    """The first config key where the shipped run's recipe differs from the one the demo would train it with,
    as ``key=shipped (the demo: expected)``; None if none.

    Runs are compared phase by phase (:func:`~edofproj.training.phases.training_phases`): a key only counts
    where a phase reads it, so the ``refit_net`` section and the ``train.refit_*`` keys of a run in one phase
    (which it never reads) do not count; neither do the keys of :data:`RECIPE_IGNORED` or the classic elements'
    keys that neither run's DOE reads (:func:`~edofproj.config.unread_doe_keys`). Runs with other phases differ
    by ``phases``. A difference is named by the key a user sets (:func:`~edofproj.training.phases.run_key`:
    ``train.refit_steps`` for the refit phase's steps)."""
    phases_a, phases_b = training_phases(shipped), training_phases(expected)
    names_a, names_b = [p.name for p in phases_a], [p.name for p in phases_b]
    if names_a != names_b:
        return f"phases={'+'.join(names_a)} (the demo: {'+'.join(names_b)})"
    unread = {f"doe.{key}" for key in unread_doe_keys(shipped.doe.kind)} & {
        f"doe.{key}" for key in unread_doe_keys(expected.doe.kind)
    }
    ignored = (*RECIPE_IGNORED, *PHASE_UNREAD)
    for phase_a, phase_b in zip(phases_a, phases_b):
        a, b = flatten_keys(to_dict(phase_a.cfg)), flatten_keys(to_dict(phase_b.cfg))
        for key in sorted(set(a) | set(b)):
            if key.startswith(ignored) or key in unread or a.get(key) == b.get(key):
                continue
            shipped_key, expected_key = run_key(phase_a, key, shipped), run_key(phase_b, key, expected)
            if shipped_key != expected_key:  # e.g. one run's refit network is its refit_net, the other's its net
                return f"{shipped_key}={a.get(key)!r} (the demo: {expected_key}={b.get(key)!r})"
            return f"{shipped_key}={a.get(key)!r} (the demo: {b.get(key)!r})"
    return None


def use_builtin_baselines(jobs: Sequence[TrainingJob], overrides: Sequence[str], training_config: str) -> None:
    """Put a shipped run of each skipped baseline (:data:`BUILTIN_BASELINES`) in its run directory,
    with the evaluation keys of ``overrides`` applied, and mark the job ``built-in`` -- the first one
    trained with exactly the recipe the demo would train it with (``training_config`` with the job's
    overrides; :func:`recipe_difference`). Otherwise the job stays skipped and its note names the first
    difference of each shipped run."""
    for job in jobs:
        names = [name for name in BUILTIN_BASELINES.get(job.method, ()) if name in BUILTIN_RUNS]
        if job.status != "skipped" or not names:
            continue
        expected = load_config(training_config, job.overrides)
        differences = {
            name: recipe_difference(saved_config(require_trained_run(PREFIX + name)), expected) for name in names
        }
        same = [name for name in names if differences[name] is None]
        if not same:
            job.note += "".join(
                f"; its shipped run {PREFIX}{name} was trained with another recipe: {difference}"
                for name, difference in differences.items()
            )
            continue
        shipped = copy_pretrained(PREFIX + same[0], job.run_dir, overrides)
        job.status = "built-in"
        job.note = (
            f"{job.note.replace('not trained: ', 'not trained here: ')}; shipped run {shipped.source} "
            f"({shipped.steps} steps, trained beforehand with the same recipe; --retrain-baselines trains it here)"
        )


def flat_doe_note(run_dir: Path) -> str | None:
    """One sentence when the trained DOE of ``run_dir`` is still a flat plate (one height level), else
    None: then ``doe`` projects like ``lens`` and the DOE's methods show no extended depth of field."""
    path = run_dir / DOE_NAME
    if not path.is_file():
        return None
    data = read_arrays(path, "DOE file")
    heights = data["height_m"] if "height_m" in data else data.get("height_map_m")
    if heights is None or np.ptp(np.asarray(heights, dtype=float)) > 0:
        return None
    run = load_run(run_dir)
    steps = min(run.step, training_phases(run.cfg)[0].cfg.train.steps)  # the steps of the phase that moves it
    return (
        f"The DOE trained here is still the flat plate it starts as ({steps} steps moved no height by a whole "
        "level of its quantized profile), so `doe` projects like `lens`; the full demo trains long enough to "
        "shape it."
    )


def timing_rows(evaluation, settings: DemoSettings) -> list:
    """Milliseconds per compensated 3-channel frame of the evaluated methods (median)."""
    cases = []
    run_design = evaluation.designs.get("run")
    focus_m = evaluation.cfg.optics.focus_m
    by_name = {m.name: m for m in evaluation.methods}
    psf = run_design.psf([focus_m])[0].cpu().numpy() if run_design is not None else None
    if "doe+wiener" in by_name and psf is not None:
        cases.append(timing.wiener_scipy_case(psf, evaluation.nsr.get("run", 1e-3), workers=torch.get_num_threads()))
    for name in (OURS, "lens+onlineprodeb"):
        if name in by_name:  # the forward pass alone: no display guard (the summary's ms/frame has it)
            cases.append(timing.network_torch_case(by_name[name].compensate.net, f"{name} network alone"))
    results = timing.time_cases(
        cases, list(settings.timing_sizes), repeats=settings.timing_repeats, warmup=1, budget_s=TIMING_CASE_BUDGET_S
    )
    if "lens+cls" in by_name and psf is not None:
        cls_case = timing.cls_torch_case(psf, evaluation.cfg.evaluation.cls_iterations)
        results += timing.time_cases([cls_case], list(settings.timing_sizes[:1]), repeats=1, warmup=0)
    return results


def _frame_hw(evaluation) -> tuple[int, int]:
    """``(height, width)`` of the evaluated frames (the first image's)."""
    height, width = evaluation.images[0][1].shape[-2:]
    return int(height), int(width)


def timing_section(results, threads: int, evaluated_hw: tuple[int, int] | None = None) -> list:
    """The report's timing table; its paragraph says how it differs from the summary's ms/frame
    (measured on the evaluated frame size, ``evaluated_hw``)."""
    if not results:
        return []
    sizes = list(dict.fromkeys((t.height, t.width) for t in results))
    methods = list(dict.fromkeys((t.method, t.backend) for t in results))
    value = {(t.method, t.backend, t.height, t.width): t.median_ms for t in results}
    rows = [
        [m, b] + [f"{value[(m, b, h, w)]:.1f}" if (m, b, h, w) in value else "-" for h, w in sizes] for m, b in methods
    ]
    return [
        Heading("Timing"),
        Paragraph(
            f"Median milliseconds per compensated 3-channel frame on this CPU ({threads} thread(s)); "
            "the paper's Table 1 was measured on a V100 GPU. CLS: 1 frame at the smallest size. "
            "These are not the summary's ms/frame, and the two disagree: the summary times each method's "
            "whole compensation as evaluated"
            + (f" ({evaluated_hw[0]}x{evaluated_hw[1]} frames)" if evaluated_hw else "")
            + ", in PyTorch, right after scoring (the non-blind Wiener filter rebuilt for each frame), while "
            "this table times the kernels alone on random frames of fixed sizes (the Wiener filter applied from "
            "a cached transfer function with SciPy; the networks' forward pass with channels-last weights), "
            f"a few repeats each (fewer once the timed frames add up to {TIMING_CASE_BUDGET_S:g} s). Both are wall "
            "clock on whatever else the machine runs: on a shared machine the "
            "same frame can take several times longer from one minute to the next (`edofproj bench` repeats "
            "more)."
        ),
        Table(["method", "backend"] + [f"{h}x{w}" for h, w in sizes], rows),
    ]


def preset_elements(preset, run_config: str | Path) -> list[str]:
    """``doe.KEY=VALUE`` overrides that give the configuration ``run_config`` (a trained run's) the classic
    elements of ``preset`` (tuned for its projector and range), for the keys its DOE never reads
    (:func:`~edofproj.config.unread_doe_keys`): its baselines and their linear filters then use them."""
    kind = load_config(str(run_config)).doe.kind
    return [f"doe.{key}={getattr(preset.doe, key)}" for key in unread_doe_keys(kind)]


@dataclass(frozen=True)
class PretrainedOurs:
    """A trained run that stands for ``doe+net`` in a demo: where it came from and its steps."""

    source: str
    steps: int


def pretrained_baseline_overrides(source_cfg) -> list[str]:
    """The overrides that give a baseline of ``demo --pretrained`` :data:`PRETRAINED_BASELINE_CROPS` training
    crops of the pretrained run's last phase (a fixed element's network trains the refit phase alone,
    :mod:`edofproj.training.phases`): ``train.steps`` of a one-phase run; ``train.refit_steps`` of a run in two
    phases, with its refit warm-up the same fraction of the phase as in the run's recipe."""
    last = training_phases(source_cfg)[-1].cfg.train
    steps = max(1, PRETRAINED_BASELINE_CROPS // last.batch_size)
    if not source_cfg.train.refit_steps:
        return [f"train.steps={steps}"]
    warmup = source_cfg.train.refit_warmup_steps * steps // source_cfg.train.refit_steps
    return [f"train.refit_steps={steps}", f"train.refit_warmup_steps={warmup}"]


def copy_pretrained(source: str | Path, run_dir: Path, overrides: Sequence[str]) -> PretrainedOurs:
    """Copy the trained run ``source`` (a directory or ``builtin:NAME``) to ``run_dir``, applying the
    evaluation keys of ``overrides`` (``evaluation.*``, ``imaging.*``, ``data.max_test_images``, and the
    classic elements' keys its DOE never reads: :func:`~edofproj.evaluation.pipeline.is_evaluation_key`) to
    its configuration; the rest of the configuration is what the run was trained with (written in the
    current format: a configuration of an older one is converted once, here)."""
    source_dir = require_trained_run(source)
    shutil.copytree(source_dir, run_dir, ignore=shutil.ignore_patterns(".*"))
    trained = saved_config(source_dir)
    evaluation_keys = [o for o in overrides if is_evaluation_key(o.split("=", 1)[0], trained)]
    write_run_config(run_dir, apply_overrides(trained, evaluation_keys))
    return PretrainedOurs(str(source), int(load_run(run_dir).step))


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise EdofprojError(f"--out '{out}' exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        raise EdofprojError(f"--out '{out}' is not empty: choose another directory or remove it")


@dataclass
class DemoResult:
    out: Path
    evaluation: Evaluation
    claims: list[Claim]
    jobs: list[TrainingJob]
    wall_s: float
    report_html: Path


def run_demo(
    out: str | Path,
    quick: bool = False,
    config: str = "cpu",
    methods: Sequence[str] | None = None,
    overrides: Sequence[str] = (),
    workers: int = 2,
    budget_s: float | None = None,
    timing: bool = True,
    progress: StageProgress | None = None,
    pretrained: str | Path | None = None,
    retrain_baselines: bool = False,
) -> DemoResult:
    """Run the demo into ``out`` (module docstring); returns what it measured and wrote.

    ``pretrained``: a trained run (directory or ``builtin:NAME``) copied to ``doe_net/`` instead of
    training ``doe+net``; the baselines train with its configuration (its projector: optics, spectrum,
    PSF sampling) for the steps of :func:`demo_jobs`. ``retrain_baselines``: train every
    baseline whatever the budget (else those predicted not to fit come from the shipped runs)."""
    clock = time.perf_counter()
    settings = QUICK if quick else FULL
    budget = float(budget_s) if budget_s is not None else settings.budget_s
    for name in methods or ():
        method_spec(name)
    if methods and OURS not in methods:
        raise EdofprojError(f"--methods must include {OURS} (the demo trains and evaluates it)")
    out = Path(out)
    _check_out(out)
    cfg = load_config(config, list(settings.overrides) + list(overrides))  # validates every override up front
    if cfg.data.source == "folder" and not cfg.data.folder:
        raise EdofprojError("the demo uses built-in data; data.source=folder needs data.folder")
    progress = progress or StageProgress("demo", enabled=False)

    if pretrained is not None:
        require_trained_run(pretrained)  # fails before anything is written
    training_config = config
    steps_set = sets_steps([*settings.overrides, *overrides])
    if pretrained is not None:
        # the baselines must share the pretrained run's projector (optics, spectrum, PSF sampling): they
        # train with its configuration (its network and phases) for PRETRAINED_BASELINE_CROPS, with the
        # preset's classic elements where the pretrained run's DOE does not read them
        source = require_trained_run(pretrained)
        training_config = str(source / "config.yaml")
        steps = pretrained_baseline_overrides(saved_config(source))
        overrides = [*steps, *preset_elements(cfg, training_config), *overrides]
        cfg = load_config(training_config, list(settings.overrides) + list(overrides))
    jobs = demo_jobs(
        out,
        settings,
        cfg,
        methods,
        overrides,
        train_ours=pretrained is None,
        retrain_baselines=retrain_baselines,
        steps_set=steps_set,
    )
    planned = demo_methods(settings, methods)
    later = evaluation_seconds(settings, cfg, planned) + (TIMING_ESTIMATE_S[settings.name] if timing else 0.0)
    deadline = clock + budget - later - REPORT_MARGIN_S
    out.mkdir(parents=True, exist_ok=True)
    ours = None
    if pretrained is not None:
        ours = copy_pretrained(pretrained, out / OURS_RUN_DIR, list(settings.overrides) + list(overrides))

    def predict_on_this_machine(measured: ParallelTrainer) -> None:
        # the later stages run on the same CPU: they scale with the measured step (ParallelTrainer.speed)
        total_s = time.perf_counter() - clock + measured.planned_seconds + measured.later_seconds() + REPORT_MARGIN_S
        progress.note(prediction_note(total_s, budget, measured.reference_rate_s(), cfg))

    # the cubic plate's PSFs for the evaluation, on the core a training worker leaves free at the end
    prefetch = DesignPrefetch(out / OURS_RUN_DIR, planned)
    trainer = ParallelTrainer(
        jobs,
        training_config,
        out / LOG_DIR,
        workers,
        deadline,
        progress,
        reference_rate_s(cfg),
        later_s=later,
        on_measured=predict_on_this_machine,
        on_idle_worker=prefetch.start,
    )
    trainer.plan()  # before any training: the baselines predicted not to fit are named now
    use_builtin_baselines(jobs, list(settings.overrides) + list(overrides), training_config)
    progress.note(plan_line(jobs))
    progress.start("stage 1/4 training", trainer.total_work(), later_s=later)
    try:
        trainer.run()
    finally:
        simulated = prefetch.finish()
    use_builtin_baselines(jobs, list(settings.overrides) + list(overrides), training_config)
    progress.finish(", ".join(f"{j.method}: {j.status}" for j in jobs))

    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    progress.note("stage 2/4 evaluation")
    trained = {j.method for j in jobs if j.status in ("done", "built-in")}
    eval_methods = [m for m in planned if not method_spec(m).needs_separate_run or m in trained]
    evaluation = evaluate_run(
        out / OURS_RUN_DIR,
        out_dir=out,
        methods=eval_methods,
        baselines_dir=out,
        progress=progress,
        designs=simulated,
    )
    for job in jobs:
        if job.status not in ("done", "built-in"):
            evaluation.notes.append(f"{job.method} not evaluated: {job.note or job.status}")

    timings = []
    if timing:
        progress.start("stage 3/4 timing", 1)
        timings = timing_rows(evaluation, settings)
        progress.finish()
    scene_blocks = scene_section(out, evaluation.methods, quick, progress)
    surface_blocks = surface_section(out, evaluation.methods, progress)

    progress.start("stage 4/4 report", 1)
    claims = ssim_claims(evaluation.table, evaluation.range_mm)
    wall_s = time.perf_counter() - clock
    claims.append(wall_time_claim(wall_s, budget))
    if quick:  # a smoke run measures the claims on tiny images and few steps: it judges nothing
        claims = [dataclasses.replace(claim, judged=False) for claim in claims]
    preface = [
        Heading("Demo"),
        Paragraph(
            f"`edofproj demo{' --quick' if quick else ''}{' --pretrained' if ours else ''}`: preset '{config}', "
            + (f"{OURS} the trained run {ours.source} ({ours.steps} steps, trained beforehand), " if ours else "")
            + steps_sentence(jobs)
            + phases_sentence(jobs, training_config)
            + f", built-in photographs only. Wall time {format_duration(wall_s, unit=True)} "
            f"up to the report, budget {format_duration(budget, unit=True)}."
            + (" A quick smoke run: few steps and tiny images; its quality is not meant to be judged." if quick else "")
        ),
        jobs_table(jobs, ours),
    ]
    flat = flat_doe_note(out / OURS_RUN_DIR)
    if flat:
        preface.append(Paragraph(flat))
    preface += claims_section(claims)
    paths = write_documents(
        evaluation,
        title="edofproj demo report",
        preface=preface,
        extra=timing_section(timings, torch.get_num_threads(), _frame_hw(evaluation)) + scene_blocks + surface_blocks,
    )
    progress.finish()
    return DemoResult(out, evaluation, claims, jobs, time.perf_counter() - clock, paths["report_html"])


def scene_section(out: Path, evaluated: Sequence[PreparedMethod], quick: bool, progress: StageProgress) -> list:
    """Score the methods on :data:`DEMO_SCENE` (first held-out image) and return the report's blocks;
    ``evaluated``: the flat-screen evaluation's methods, scored as they are (not built again)."""
    methods = [m.name for m in evaluated]
    # the classic elements' linear baselines are scored on flat screens only (their 2-D PSFs at the scene's layers)
    chosen = (
        [m for m in methods if m in QUICK_SCENE_METHODS]
        if quick
        else [m for m in methods if method_spec(m).optics not in CLASSIC_ELEMENTS]
    )
    progress.note(f"scene {DEMO_SCENE}")
    try:
        scenes = evaluate_scenes(
            out / OURS_RUN_DIR,
            [DEMO_SCENE],
            out_dir=out,
            methods=chosen,
            baselines_dir=out,
            overrides=["data.max_test_images=1"],
            built=evaluated,
        )
    except EdofprojError as exc:  # e.g. a configuration whose PSF range does not cover the scene
        return [Heading("Projection onto a 3-D scene"), Paragraph(f"Scene `{DEMO_SCENE}` not scored: {exc}.")]
    write_scene_report(scenes)
    low, high = scenes.depth_ranges_mm[DEMO_SCENE]
    table = scene_summary_table(scenes, "ssim")
    table.caption = "SSIM over the object's pixels"
    return [
        Heading("Projection onto a 3-D scene"),
        Paragraph(
            f"Scene `{DEMO_SCENE}`: a sphere of radius 80 mm at 420 mm in front of a wall at 750 mm, seen at "
            f"{low:.0f}-{high:.0f} mm over the whole {scenes.table.rows[0]['image']} image; each projector pixel "
            "carries the PSF of the surface it lands on. `edofproj evaluate RUN --scene builtin` scores every "
            f"built-in scene ({scenes.seconds:.0f} s here)."
        ),
        table,
        Figure(scenes.files["figure"], "Rows: scenes; columns: the target on the object and each method."),
        Figure(scenes.files["ssim_figure"], "Local SSIM on the object (white = 1)."),
    ]


def surface_section(out: Path, evaluated: Sequence[PreparedMethod], progress: StageProgress) -> list:
    """Score the demo's blind methods, their photometric variants and cascades on :data:`DEMO_SURFACE`
    (first held-out image, ambient :data:`DEMO_AMBIENT`) and return the report's blocks; ``evaluated``: the
    flat-screen evaluation's methods, scored as they are (not built again)."""
    progress.note(f"textured surface {DEMO_SURFACE}")
    try:
        surfaces = evaluate_surfaces(
            out / OURS_RUN_DIR,
            [DEMO_SURFACE],
            out_dir=out,
            ambient=DEMO_AMBIENT,
            baselines_dir=out,
            overrides=["data.max_test_images=1"],
            built=evaluated,
        )
    except EdofprojError as exc:
        return [
            Heading("Projection onto a textured surface"),
            Paragraph(f"Surface `{DEMO_SURFACE}` not scored: {exc}."),
        ]
    write_surface_report(surfaces)
    summary = surface_summary_table(surfaces, DEMO_SURFACE)
    return [
        Heading("Projection onto a textured surface"),
        Paragraph(
            f"The built-in texture `{DEMO_SURFACE}` (a reflectance never used in training) as a flat screen at each "
            f"depth, ambient light {DEMO_AMBIENT:g} of the projector's white, the first held-out image; every method "
            "is scored against the goal, the target scaled into what the surface can show. `+photometric` divides "
            "by the reflectance first (for a network: then the network deblurs). The demo trains no surface-aware "
            "network (`--set net.surface_input=true` trains one; `edofproj evaluate RUN --surface builtin` scores "
            f"every built-in texture) ({surfaces.seconds:.0f} s here)."
        ),
        Table(summary.header, summary.rows, caption="SSIM and PSNR against the goal"),
        Figure(
            surfaces.files["figure"],
            "The reflectance, the goal and each method's projection at the nearest scored depth, then SSIM over depth.",
        ),
    ]


def demo_finished_message(result: DemoResult) -> str:
    lines = [format_text_table(range_table(result.evaluation.table, result.evaluation.range_mm, ["ssim", "psnr"])), ""]
    lines += [f"claim ({c.key}) {c.verdict}: {c.statement} -- {c.measured}" for c in result.claims]
    lines += [
        "",
        f"report: {result.report_html}",
        f"(markdown: {result.report_html.with_suffix('.md')}; total {format_duration(result.wall_s, unit=True)})",
    ]
    return "\n".join(lines)
