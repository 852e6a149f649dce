"""``evaluate``: score a trained run and its baselines on held-out images; write the tables of scores.

The straight line of an evaluation:

1. load the run (config, fabricated DOE, network) and the separate baseline runs found in the
   baselines directory (:data:`~edofproj.methods.catalogue.BASELINE_RUN_DIRS`; default: the
   run's parent directory, where the demo puts them side by side);
2. build the methods (:mod:`edofproj.methods`: optical designs and their PSFs, the Wiener NSR of
   each design tuned on *training* crops, the networks behind their display guard);
3. score every method on every held-out image at every depth (:func:`.sweep.flat_screen_sweep`)
   and on the tilted screen (:func:`.sweep.tilted_screen_sweep`);
4. write ``metrics.csv`` and ``tilted_metrics.csv`` into the output directory. The figures and
   documents about the scores are :mod:`edofproj.reporting.writeup`'s.

A method whose run does not exist is skipped with a note, unless it was asked for by name.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import torch

from ..builtin_runs import require_output_outside
from ..config import Config, apply_overrides, unread_doe_keys
from ..data import evaluation_images
from ..data.validation import validation_images
from ..errors import EdofprojError
from ..methods.builder import MethodBuilder, PreparedMethod, require_trained_run
from ..methods.catalogue import select_methods
from ..methods.compensators import ensemble_depths_m, score_range_mm
from ..methods.designs import DEPTH_KEY_RESOLUTION_M, OpticalDesign
from ..methods.guard import guard_depths_m, guard_notes
from ..optics.geometry import check_screen_depths_mm
from ..progress import StageProgress
from ..runs import TrainedRun, load_run
from .results import MetricsTable
from .sweep import (
    PERCEPTUAL_COLUMNS,
    TiltedScreen,
    depth_notes,
    example_displays,
    flat_screen_sweep,
    load_perceptual_metrics,
    nearest_scored_depths_mm,
    scored_range_mm,
    tilted_screen_sweep,
    trained_range_mm,
)
from .timing import time_methods

METRICS_NAME = "metrics.csv"
TILTED_METRICS_NAME = "tilted_metrics.csv"
#: Config keys ``evaluate --set`` may change (the run's training configuration stays as trained), with the
#: classic elements' keys that the run's DOE never reads (:func:`is_evaluation_key`).
EVALUATION_OVERRIDE_PREFIXES = ("evaluation.", "imaging.", "data.max_test_images")


def is_evaluation_key(key: str, cfg) -> bool:
    """True when ``evaluate --set KEY=...`` may change ``key`` of a run trained with ``cfg``: an evaluation key
    (:data:`EVALUATION_OVERRIDE_PREFIXES`), or a classic element's ``doe`` key that the run's DOE never reads
    (:func:`~edofproj.config.unread_doe_keys`: it sets the element of the ``X``, ``X+wiener``, ``X+ensemble``
    baselines, e.g. ``doe.cubic_waves`` for a learned DOE's run)."""
    key = key.strip()
    return key.startswith(EVALUATION_OVERRIDE_PREFIXES) or key in {f"doe.{k}" for k in unread_doe_keys(cfg.doe.kind)}


@dataclass
class Evaluation:
    """Everything an evaluation measured and wrote (``figures`` is filled by
    :func:`edofproj.reporting.writeup.write_figures`)."""

    out_dir: Path
    run: TrainedRun
    cfg: Config  # the run's config with the evaluation overrides
    methods: list[PreparedMethod]
    designs: dict[str, OpticalDesign]
    images: list[tuple[str, torch.Tensor]]
    depths_mm: list[float]
    range_mm: tuple[float, float]
    table: MetricsTable
    tilted: MetricsTable
    comparison: dict
    tilted_examples: dict
    notes: list[str] = field(default_factory=list)
    nsr: dict[str, float] = field(default_factory=dict)
    perceptual: list[str] = field(default_factory=list)
    perceptual_missing: list[str] = field(default_factory=list)
    baseline_runs: dict[str, TrainedRun] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, Path] = field(default_factory=dict)
    seconds: float = math.nan
    #: Median milliseconds per compensated frame of each method (:func:`.timing.time_methods`).
    frame_ms: dict[str, float] = field(default_factory=dict)
    timing_threads: int = 0
    #: Which images were scored: ``test`` (held out), ``validation`` or ``folder`` (``--images``).
    image_set: str = "test"


# --------------------------------------------------------------------------- evaluation


def evaluation_config(cfg, overrides: Sequence[str] = ()):
    """The run's config with ``--set`` overrides of the evaluation keys only (:func:`is_evaluation_key`)."""
    for item in overrides or ():
        key = item.split("=", 1)[0].strip()
        if not is_evaluation_key(key, cfg):
            raise EdofprojError(
                f"--set {key}: evaluate only changes evaluation.*, imaging.*, data.max_test_images and the classic "
                f"elements' doe keys that a doe.kind={cfg.doe.kind} run does not read (the rest is the run's "
                "trained configuration)"
            )
    return apply_overrides(cfg, overrides) if overrides else cfg


@dataclass(frozen=True)
class OpenedRun:
    """A trained run opened for evaluation: its directory, where the files go, the run and its
    evaluation config (the run's config with the ``--set`` evaluation overrides)."""

    run_path: Path
    out_dir: Path
    run: TrainedRun
    cfg: Config

    def method_builder(
        self, baselines_dir: str | Path | None, explicit: bool, device: str | torch.device = "cpu"
    ) -> MethodBuilder:
        """A :class:`MethodBuilder` for this run; the baseline runs are looked for in ``baselines_dir``
        (default: the run's parent directory)."""
        return MethodBuilder(
            self.run,
            self.cfg,
            Path(baselines_dir) if baselines_dir is not None else self.run_path.parent,
            explicit=explicit,
            device=device,
        )


def design_depths_m(cfg, compensations: Iterable[str], depths_mm: Sequence[float] | None = None) -> np.ndarray:
    """The distinct depths (m, ascending; equal to :data:`~edofproj.methods.designs.DEPTH_KEY_RESOLUTION_M`)
    at which :func:`evaluate_run` simulates the PSFs of one design whose methods use ``compensations``
    (:attr:`~edofproj.methods.catalogue.MethodSpec.compensation`): the flat-screen sweep (``depths_mm``,
    default ``evaluation.depths_mm``), the in-focus depth (timing), the tilted screen's layers and centre,
    and the compensations' own: the Wiener NSR tuning depths (``wiener``, ``ensemble``), the depth-ensemble
    filter's depths (``ensemble``) and a guarded network's (``net``, with ``evaluation.display_guard``).
    What the 2-D engine costs an evaluation is this count times its seconds per depth."""
    compensations = set(compensations)
    near_mm, far_mm = score_range_mm(cfg)
    sweep_mm = depths_mm if depths_mm is not None else cfg.evaluation.depths_mm
    tilted = TiltedScreen(cfg, 2, 2)
    parts = [np.asarray(sweep_mm, dtype=float) * 1e-3, [cfg.optics.focus_m, tilted.centre_m], tilted.layers_m]
    if compensations & {"wiener", "ensemble"}:
        parts.append(np.linspace(near_mm, far_mm, cfg.evaluation.wiener_tuning_depths) * 1e-3)
    if "ensemble" in compensations:
        parts.append(ensemble_depths_m(cfg))
    if "net" in compensations and cfg.evaluation.display_guard:
        parts.append(guard_depths_m(near_mm * 1e-3, far_mm * 1e-3))
    keys = np.unique(
        np.round(np.concatenate([np.atleast_1d(np.asarray(p, dtype=float)) for p in parts]) / DEPTH_KEY_RESOLUTION_M)
    )
    return keys * DEPTH_KEY_RESOLUTION_M


def open_run(run_dir: str | Path, out_dir: str | Path | None, overrides: Sequence[str] = ()) -> OpenedRun:
    """Check and load the trained run in ``run_dir`` for an evaluation writing to ``out_dir``
    (default: the run itself, allowed only outside the built-in runs); one-line errors."""
    run_path = require_trained_run(run_dir)
    if out_dir is None:
        require_output_outside(run_path, "an output directory (--out)")
    out = Path(out_dir) if out_dir is not None else run_path
    run = load_run(run_path)
    return OpenedRun(run_path, out, run, evaluation_config(run.cfg, overrides))


def evaluate_run(
    run_dir: str | Path,
    out_dir: str | Path | None = None,
    images_dir: str | Path | None = None,
    depths_mm: Sequence[float] | None = None,
    methods: Sequence[str] | None = None,
    baselines_dir: str | Path | None = None,
    overrides: Sequence[str] = (),
    progress: StageProgress | None = None,
    device: str | torch.device = "cpu",
    timing: bool = True,
    validation: bool = False,
    designs: Sequence[OpticalDesign] = (),
) -> Evaluation:
    """Evaluate the run in ``run_dir`` (module docstring); files go to ``out_dir`` (default: the run).

    ``device``: where the images, PSFs and networks are run (``cpu`` or ``cuda``); the PSFs are
    simulated on the CPU, and the tables do not depend on the device beyond float32 rounding.
    ``timing``: time each method's compensation of one frame (the first image, at the in-focus
    depth; :func:`.timing.time_methods`). ``validation``: score the built-in validation set
    (:mod:`edofproj.data.validation`) instead of the test images. ``designs``: optical designs already
    simulated with this evaluation's configuration, their cached PSFs reused (:meth:`MethodBuilder.adopt`)."""
    clock = time.perf_counter()
    specs = select_methods(methods)  # unknown names fail before any work
    if depths_mm is not None:
        depths_mm = [float(z) for z in check_screen_depths_mm(depths_mm, "--depths-mm")]
    opened = open_run(run_dir, out_dir, overrides)
    run, cfg, out = opened.run, opened.cfg, opened.out_dir
    progress = progress or StageProgress("evaluate", enabled=False)
    depths = sorted(set(depths_mm if depths_mm is not None else [float(z) for z in cfg.evaluation.depths_mm]))
    if depths_mm is not None:  # the sizes of the sweep asked for, before anything is simulated
        dataclasses.replace(cfg, evaluation=dataclasses.replace(cfg.evaluation, depths_mm=depths)).check_memory()
    range_mm = scored_range_mm(depths, score_range_mm(cfg))  # what the tables cover, stated in their headings
    asked = depth_notes(depths, trained_range_mm(cfg), score_range_mm(cfg)) if depths_mm is not None else []
    if validation and images_dir is not None:
        raise EdofprojError("--validation and --images are two image sets: give one")
    with warnings.catch_warnings(record=True) as skipped:
        warnings.simplefilter("always")
        if validation:
            size = cfg.evaluation.image_size
            images = validation_images(
                (int(size[0]), int(size[1])) if size else None,
                cfg.evaluation.image_scaling,
                int(cfg.data.max_test_images or 0),
            )
        else:
            images = evaluation_images(cfg, images_dir)
    # skipped images become notes: printed like the other notes and named in the report
    image_notes = [str(w.message) for w in skipped if str(w.message).startswith("skipping")]
    for warning in skipped:
        if str(warning.message) not in image_notes:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    if image_notes:
        small = sum("smaller than the evaluation size" in note for note in image_notes)
        counts = [(len(image_notes) - small, "as unreadable"), (small, "as smaller than the evaluation size")]
        skipped_text = ", ".join(f"{n} skipped {why}" for n, why in counts if n)
        image_notes.append(f"{len(images)} image(s) scored; {skipped_text}")

    progress.start("preparing methods", len(specs), detail="PSFs, Wiener NSR tuning, networks")
    builder = opened.method_builder(baselines_dir, explicit=bool(methods), device=device)
    builder.adopt(designs)
    prepared = builder.build_all(specs, progress)
    builder.notes.extend(image_notes + asked)
    for note in builder.notes:
        progress.note(note)

    perceptual = {name: metric.to(device) for name, metric in load_perceptual_metrics(cfg.loss.weights_dir).items()}

    missing = [c for c in PERCEPTUAL_COLUMNS if c not in perceptual]

    units = len(prepared) * len(images)
    progress.start(
        "flat-screen sweep",
        units * len(depths),
        detail=f"{len(prepared)} methods x {len(depths)} depths x {len(images)} images",
    )
    table = flat_screen_sweep(prepared, images, depths, perceptual, progress.advance, device)
    progress.finish()
    builder.notes.extend(guard_notes(prepared))
    progress.start("tilted screen", units)
    tilted, tilted_examples = tilted_screen_sweep(prepared, images, cfg, perceptual, progress.advance, device)
    comparison_depths = nearest_scored_depths_mm(cfg.evaluation.comparison_depths_mm, depths)
    comparison = example_displays(prepared, images[0][1], comparison_depths, perceptual, device)
    progress.finish()

    frame_ms: dict[str, float] = {}
    if timing:
        progress.start("timing", 1, detail="milliseconds per compensated frame")
        frame_ms = time_methods(prepared, images[0][1].to(device), cfg.optics.focus_mm * 1e-3)
        progress.finish()

    evaluation = Evaluation(
        out_dir=out,
        run=run,
        cfg=cfg,
        methods=prepared,
        designs=builder.designs,
        images=images,
        depths_mm=depths,
        range_mm=range_mm,
        table=table,
        tilted=tilted,
        comparison=comparison,
        tilted_examples=tilted_examples,
        notes=builder.notes,
        nsr=builder.nsr,
        perceptual=list(perceptual),
        perceptual_missing=missing,
        baseline_runs=builder.baseline_runs,
        frame_ms=frame_ms,
        timing_threads=torch.get_num_threads(),
        image_set="validation" if validation else ("folder" if images_dir is not None else "test"),
    )
    write_tables(evaluation)
    evaluation.seconds = time.perf_counter() - clock
    return evaluation


# --------------------------------------------------------------------------- files


def write_tables(ev: Evaluation) -> None:
    ev.out_dir.mkdir(parents=True, exist_ok=True)
    ev.files["metrics"] = ev.out_dir / METRICS_NAME
    ev.table.write_csv(ev.files["metrics"])
    ev.files["tilted_metrics"] = ev.out_dir / TILTED_METRICS_NAME
    ev.tilted.write_csv(ev.files["tilted_metrics"])
