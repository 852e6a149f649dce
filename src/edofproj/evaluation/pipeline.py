"""``evaluate``: score a trained run and its baselines on held-out images; write the tables of scores.

The straight line of an evaluation:

1. load the run (config, fabricated DOE, network) and the separate baseline runs found in the
   baselines directory (:data:`~edofproj.evaluation.methods.BASELINE_RUN_DIRS`; default: the
   run's parent directory, where the demo puts them side by side);
2. prepare the methods (:mod:`.methods`): optical designs and their PSFs (:mod:`.designs`), the
   Wiener NSR of each design tuned on *training* crops, the networks;
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
from typing import Sequence

import torch

from ..builtin_runs import require_output_outside, resolve_run_dir
from ..compensation.registry import describe_network
from ..config import Config, apply_overrides, to_dict, without_statements
from ..data import evaluation_images
from ..data.validation import validation_images
from ..doe import build_doe
from ..errors import EdofprojError
from ..optics.geometry import check_screen_depths_mm
from ..progress import StageProgress
from ..runs import CONFIG_NAME, TrainedRun, last_checkpoint_path, load_run
from .designs import OpticalDesign
from .guard import GuardedNetworkCompensation, guard_depths_m, guard_notes, network_filter
from .methods import (
    ConstrainedCompensation,
    EnsembleWienerCompensation,
    MethodSpec,
    NetworkCompensation,
    PreparedMethod,
    WienerCompensation,
    ensemble_depths_m,
    ensemble_radius,
    no_compensation,
    score_range_mm,
    select_methods,
    training_crops,
    tune_ensemble_nsr,
    tune_nsr,
)
from .results import MetricsTable
from .sweep import (
    PERCEPTUAL_COLUMNS,
    depth_notes,
    example_displays,
    flat_screen_sweep,
    load_perceptual_metrics,
    scored_range_mm,
    tilted_screen_sweep,
    trained_range_mm,
)
from .timing import time_methods

METRICS_NAME = "metrics.csv"
TILTED_METRICS_NAME = "tilted_metrics.csv"
#: Config sections a baseline run must share with the evaluated run (same projector, same light).
SHARED_SECTIONS = ("optics", "spectrum")
#: Config keys ``evaluate --set`` may change (the run's training configuration stays as trained).
EVALUATION_OVERRIDE_PREFIXES = ("evaluation.", "imaging.", "data.max_test_images")


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


# --------------------------------------------------------------------------- runs


def require_trained_run(run_dir: str | Path) -> Path:
    """The run directory (a path or ``builtin:NAME``), or a one-line error when it is missing or has
    no checkpoint."""
    path = resolve_run_dir(run_dir)
    if not path.is_dir():
        raise EdofprojError(f"run directory '{run_dir}' does not exist")
    if not (path / CONFIG_NAME).is_file():
        raise EdofprojError(f"'{run_dir}' is not a training run (no {CONFIG_NAME})")
    if not last_checkpoint_path(path).is_file():
        raise EdofprojError(f"run '{run_dir}' has no checkpoint ({last_checkpoint_path(path)}): train it first")
    return path


def evaluation_config(cfg, overrides: Sequence[str] = ()):
    """The run's config with ``--set`` overrides of the evaluation keys only."""
    for item in overrides or ():
        key = item.split("=", 1)[0].strip()
        if not key.startswith(EVALUATION_OVERRIDE_PREFIXES):
            raise EdofprojError(
                f"--set {key}: evaluate only changes evaluation.*, imaging.* and data.max_test_images "
                "(the rest is the run's trained configuration)"
            )
    return apply_overrides(cfg, overrides) if overrides else cfg


def _expected_keys(spec: MethodSpec) -> dict[str, str]:
    return dict(item.split("=", 1) for item in spec.train_overrides)


def baseline_mismatch(spec: MethodSpec, path: Path, cfg, baseline_cfg) -> str | None:
    """Why the baseline run at ``path`` cannot stand for ``spec`` next to ``cfg`` (None: it can)."""
    flat = {"doe.kind": baseline_cfg.doe.kind, "net.architecture": baseline_cfg.net.architecture}
    for key, value in _expected_keys(spec).items():
        if key in flat and flat[key] != value:
            return f"its config has {key}={flat[key]}, expected {value}"
    for section in SHARED_SECTIONS:
        if without_statements(section, to_dict(getattr(baseline_cfg, section))) != without_statements(
            section, to_dict(getattr(cfg, section))
        ):
            return f"its {section} section differs from the evaluated run's (a different projector)"
    return None


# --------------------------------------------------------------------------- preparation


class MethodBuilder:
    """Builds :class:`PreparedMethod` objects, sharing designs and tuned NSRs between methods."""

    def __init__(
        self, run: TrainedRun, cfg: Config, baselines_dir: Path, explicit: bool, device: str | torch.device = "cpu"
    ) -> None:
        self.device = torch.device(device)
        self.run = run
        self.cfg = cfg
        self.baselines_dir = baselines_dir
        self.explicit = explicit
        self.designs: dict[str, OpticalDesign] = {}
        self.nsr: dict[str, float] = {}
        self.notes: list[str] = []
        self.baseline_runs: dict[str, TrainedRun] = {}
        self._build_doe = build_doe
        self._train_images: torch.Tensor | None = None

    def design(self, key: str, label: str, doe) -> OpticalDesign:
        if key not in self.designs:
            self.designs[key] = OpticalDesign(key, label, doe, self.cfg, self.device)
        return self.designs[key]

    def lens(self) -> OpticalDesign:
        return self.design("lens", "lens", self._build_doe(self.cfg, "lens"))

    def run_design(self) -> OpticalDesign:
        return self.design("run", "doe", self.run.doe)

    def train_images(self) -> torch.Tensor:
        if self._train_images is None:
            self._train_images = training_crops(
                self.cfg, self.cfg.evaluation.wiener_tuning_images, seed=self.cfg.train.seed
            ).to(self.device)
        return self._train_images

    def tuned_nsr(self, design: OpticalDesign) -> float:
        if design.key not in self.nsr:
            self.nsr[design.key], _ = tune_nsr(design, self.train_images(), self.cfg)
        return self.nsr[design.key]

    def tuned_ensemble_nsr(self, design: OpticalDesign) -> float:
        key = f"{design.key}+ensemble"
        if key not in self.nsr:
            self.nsr[key], _ = tune_ensemble_nsr(design, self.train_images(), self.cfg)
        return self.nsr[key]

    def baseline(self, spec: MethodSpec) -> TrainedRun | None:
        """The separate run of ``spec``, or None (with a note) when it is missing or unsuitable."""
        if spec.run_dir is None:
            raise EdofprojError(f"method {spec.name} has no separate run")
        path = self.baselines_dir / spec.run_dir
        if not last_checkpoint_path(path).is_file():
            reason = f"no trained run at '{path}'"
            hint = " ".join(f"--set {o}" for o in spec.train_overrides)
            if self.explicit:
                raise EdofprojError(
                    f"method {spec.name} needs {reason} (train one: edofproj train --config "
                    f"<config> --out {path} {hint})"
                )
            self.notes.append(f"{spec.name} skipped: {reason}")
            return None
        baseline = load_run(path)
        problem = baseline_mismatch(spec, path, self.cfg, baseline.cfg)
        if problem:
            if self.explicit:
                raise EdofprojError(f"method {spec.name}: the run '{path}' does not fit: {problem}")
            self.notes.append(f"{spec.name} skipped: the run '{path}' does not fit: {problem}")
            return None
        self.baseline_runs[spec.name] = baseline
        return baseline

    def build_all(self, specs, progress: StageProgress) -> list[PreparedMethod]:
        """Every method of ``specs`` that can be built here (the others leave a note), advancing ``progress``
        once per method; raises :class:`EdofprojError` when none can."""
        prepared = []
        for spec in specs:
            method = self.build(spec)
            if method is not None:
                prepared.append(method)
            progress.advance(1, detail=spec.name)
        if not prepared:
            raise EdofprojError("no method could be evaluated: " + "; ".join(self.notes))
        return prepared

    def build(self, spec: MethodSpec) -> PreparedMethod | None:
        baseline = self.baseline(spec) if spec.needs_separate_run else None
        if spec.needs_separate_run and baseline is None:
            return None
        if spec.optics == "lens":
            design = self.lens()
        elif spec.optics == "run":
            design = self.run_design()
        else:
            if baseline is None or spec.run_dir is None:
                raise EdofprojError(f"method {spec.name}: optics '{spec.optics}' needs a separate run")
            design = self.design(spec.run_dir, spec.name.split("+")[0], baseline.doe)
        detail = ""
        if spec.compensation == "none":
            compensate = no_compensation
        elif spec.compensation == "wiener":
            nsr = self.tuned_nsr(design)
            compensate = WienerCompensation(nsr)
            near_mm, far_mm = score_range_mm(self.cfg)
            detail = (
                f"NSR {nsr:.3g}, tuned for {self.cfg.evaluation.wiener_tuning_metric.upper()} on training crops "
                f"at {near_mm:.0f}-{far_mm:.0f} mm"
            )
        elif spec.compensation == "ensemble":
            nsr = self.tuned_ensemble_nsr(design)
            radius = ensemble_radius(self.cfg)
            depths_m = ensemble_depths_m(self.cfg)
            compensate = EnsembleWienerCompensation(design.psf(depths_m), nsr, radius)
            near_mm, far_mm = score_range_mm(self.cfg)
            detail = (
                f"{len(depths_m)} depths uniform in 1/z over {near_mm:.0f}-{far_mm:.0f} mm, "
                f"{2 * radius + 1}x{2 * radius + 1} taps, NSR {nsr:.3g} tuned for "
                f"{self.cfg.evaluation.wiener_tuning_metric.upper()} on training crops"
            )
        elif spec.compensation == "cls":
            compensate = ConstrainedCompensation(self.cfg.evaluation.cls_iterations)
            detail = f"{self.cfg.evaluation.cls_iterations} FISTA iterations"
        else:
            source = baseline if baseline is not None else self.run
            net = source.net.to(self.device)
            guarded = self.cfg.evaluation.display_guard and network_filter(net) is not None
            near_mm, far_mm = score_range_mm(self.cfg)
            compensate = (
                GuardedNetworkCompensation(net, design.psf(guard_depths_m(near_mm * 1e-3, far_mm * 1e-3)))
                if guarded
                else NetworkCompensation(net)
            )
            loss = source.cfg.loss
            perceptual = (
                f" + {loss.beta:g} (1 - {loss.perceptual.upper()})"
                if loss.beta > 0 and loss.perceptual != "none"
                else ""
            )
            detail = (
                f"{describe_network(source.cfg.net)}, loss {loss.alpha:g} MSE{perceptual}, {source.step} steps "
                f"({source.run_dir})" + ("; display guard on" if guarded else "")
            )
        return PreparedMethod(spec, design, compensate, detail)


# --------------------------------------------------------------------------- evaluation


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
) -> Evaluation:
    """Evaluate the run in ``run_dir`` (module docstring); files go to ``out_dir`` (default: the run).

    ``device``: where the images, PSFs and networks are run (``cpu`` or ``cuda``); the PSFs are
    simulated on the CPU, and the tables do not depend on the device beyond float32 rounding.
    ``timing``: time each method's compensation of one frame (the first image, at the in-focus
    depth; :func:`.timing.time_methods`). ``validation``: score the built-in validation set
    (:mod:`edofproj.data.validation`) instead of the test images."""
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
    comparison_depths = [float(z) for z in cfg.evaluation.comparison_depths_mm]
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
