"""A method built from a trained run, by name: the one object that every command scores, runs, times and exports.

``evaluate`` scores it (:mod:`edofproj.evaluation`), ``compensate`` and ``live`` run it, ``bench``
times it and ``export`` writes its module: what a table scores is what a command ships.

    method = build_method("builtin:cpu-doe-net", "doe+net")
    x = method.compensate(target, captured, psf)          every method (psf: the screen's, (1, 3, K, K))
    x = method.frame_function()(target, captured)        a blind method, as ``live`` runs it

A :class:`MethodBuilder` builds many methods of one run, sharing their optical designs (PSFs
simulated once) and tuned noise-to-signal ratios; the separate runs of the baselines
(``lens+net``, ``cubic+net``, ...) are found in a *baselines* directory
(:data:`~edofproj.methods.catalogue.BASELINE_RUN_DIRS`) and must share the run's projector.
A network that corrects a linear filter (``net.linear_base``) is run behind its display guard
(:mod:`.guard`) when the run's ``evaluation.display_guard`` is on, in every command alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import torch

from ..builtin_runs import resolve_run_dir
from ..compensation.registry import describe_network
from ..config import CLASSIC_DOE_KEYS, Config, to_dict, without_statements
from ..doe import build_doe
from ..errors import EdofprojError
from ..progress import StageProgress
from ..runs import CONFIG_NAME, TrainedRun, last_checkpoint_path, load_run
from .catalogue import CLASSIC_ELEMENTS, OURS, MethodSpec, method_spec
from .compensators import (
    Compensator,
    ConstrainedCompensation,
    EnsembleWienerCompensation,
    NetworkCompensation,
    WienerCompensation,
    ensemble_depths_m,
    ensemble_radius,
    no_compensation,
    score_range_mm,
    training_crops,
    tune_ensemble_nsr,
    tune_nsr,
)
from .designs import OpticalDesign
from .guard import GuardedNetworkCompensation, guard_depths_m, network_filter

#: Config sections a baseline run must share with the evaluated run (same projector, same light).
SHARED_SECTIONS = ("optics", "spectrum")
#: The ``doe`` keys every element reads (with its own, :data:`~edofproj.config.CLASSIC_DOE_KEYS`).
ELEMENT_DOE_KEYS = ("levels", "quantize", "design_wavelength_nm", "material")


def classic_element_difference(baseline_cfg, cfg, kind: str) -> str | None:
    """None when the DOE of a baseline run trained with ``baseline_cfg`` is the classic element ``kind``
    that ``cfg`` builds: the same kind and parameters, no design rules applied, and its fabricated file
    (``doe.npz``) sampled as ``cfg`` samples the pupil -- then both have the same PSFs (sampled on the
    same pupil grid, the tabulated heights are the analytic ones). Else the first difference, as
    ``key=run's value (the configuration: value)``."""
    pairs = [("doe.kind", baseline_cfg.doe.kind, kind), ("doe.min_feature_um", baseline_cfg.doe.min_feature_um, 0)]
    pairs += [(f"doe.{k}", getattr(baseline_cfg.doe, k), getattr(cfg.doe, k)) for k in ELEMENT_DOE_KEYS]
    pairs += [(f"doe.{k}", getattr(baseline_cfg.doe, k), getattr(cfg.doe, k)) for k in CLASSIC_DOE_KEYS[kind]]
    pairs.append(("psf.pupil_samples", baseline_cfg.psf.pupil_samples, cfg.psf.pupil_samples))
    for key, run_value, value in pairs:
        if run_value != value:
            return f"{key}={run_value} (the configuration: {value})"
    return None


def same_classic_element(baseline_cfg, cfg, kind: str) -> bool:
    """True when :func:`classic_element_difference` finds none."""
    return classic_element_difference(baseline_cfg, cfg, kind) is None


@dataclass
class PreparedMethod:
    """A method ready to run: its spec, its optical design, its compensation, a note for the report.

    ``compensate(target, captured, psf) -> x`` (:data:`~.compensators.Compensator`): what every command
    runs. ``module``: the ``torch.nn.Module`` it runs, when it is one (a network, or a network
    behind its display guard): what ``export`` writes and ``bench`` times; None for the others.
    """

    spec: MethodSpec
    design: OpticalDesign
    compensate: Compensator
    detail: str = ""

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def blind(self) -> bool:
        """True when the method needs neither the screen's depth nor its PSF (:attr:`MethodSpec.blind`)."""
        return self.spec.blind

    @property
    def network(self) -> torch.nn.Module | None:
        """The trained network the method runs (without its guard), None for a method without one."""
        compensate = self.compensate
        return compensate.net if isinstance(compensate, (GuardedNetworkCompensation, NetworkCompensation)) else None

    @property
    def module(self) -> torch.nn.Module | None:
        compensate = self.compensate
        if isinstance(compensate, GuardedNetworkCompensation):
            return compensate.module
        if isinstance(compensate, NetworkCompensation):
            return compensate.net
        return None

    def frame_function(self, psf: torch.Tensor | None = None) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
        """``(target, captured) -> x`` as the frame loops of ``compensate --images`` and ``live`` call it.

        A method's module itself where it has one (``live`` lays frames out for it), else its
        compensation with ``psf``; a non-blind method needs ``psf`` ``(1, 3, K, K)``, the screen's."""
        if psf is None and not self.blind:
            raise EdofprojError(
                f"method {self.name} is not blind: it needs the screen's PSF, which only a flat screen at a known "
                "depth (--depth-mm) gives"
            )
        module = self.module
        if module is not None:  # a network (behind its guard) is blind: the PSF is not used
            return module.eval()
        compensate, screen_psf = self.compensate, psf if psf is not None else torch.zeros(0)
        return lambda target, captured: compensate(target, captured, screen_psf)


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


class MethodBuilder:
    """Builds :class:`PreparedMethod` objects, sharing designs and tuned NSRs between methods."""

    def __init__(
        self,
        run: TrainedRun | None,
        cfg: Config,
        baselines_dir: Path,
        explicit: bool,
        device: str | torch.device = "cpu",
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

    def adopt(self, designs: Sequence[OpticalDesign]) -> list[str]:
        """Take ``designs`` (e.g. simulated while the demo trained) as the designs of their keys, with the PSFs
        they cached, where each was made with this builder's configuration and device and its key is not yet
        built; returns the keys taken (the others are ignored: this builder simulates its own)."""
        taken = []
        for design in designs:
            if design.key not in self.designs and design.cfg == self.cfg and design.device == self.device:
                self.designs[design.key] = design
                taken.append(design.key)
        return taken

    def design(self, key: str, label: str, doe) -> OpticalDesign:
        if key not in self.designs:
            self.designs[key] = OpticalDesign(key, label, doe, self.cfg, self.device)
        return self.designs[key]

    def lens(self) -> OpticalDesign:
        return self.design("lens", "lens", self._build_doe(self.cfg, "lens"))

    def run_design(self) -> OpticalDesign:
        return self.design("run", "doe", self._require_run().doe)

    def classic_design(self, kind: str) -> OpticalDesign:
        """The classic element ``kind`` built from the evaluated configuration (``X``, ``X+wiener``, ...)."""
        return self.design(kind, kind, self._build_doe(self.cfg, kind))

    def baseline_design(self, spec: MethodSpec, baseline: TrainedRun) -> OpticalDesign:
        """The optics of the baseline run of ``spec``: :meth:`classic_design` when its DOE is that element
        with the evaluated configuration's parameters (:func:`same_classic_element`: one design, each PSF
        simulated once for all of the element's methods), else its own DOE."""
        kind = baseline.cfg.doe.kind
        if kind in CLASSIC_ELEMENTS:
            difference = classic_element_difference(baseline.cfg, self.cfg, kind)
            if difference is None:
                return self.classic_design(kind)
            if not difference.startswith("psf."):  # a different element, not just sampled otherwise
                self.notes.append(
                    f"{spec.name}: its run's {kind} is not the one the evaluated configuration builds for the "
                    f"{kind}'s linear baselines ({difference}); `evaluate --set doe.KEY=VALUE` sets theirs"
                )
        if spec.run_dir is None:
            raise EdofprojError(f"method {spec.name} has no separate run")
        return self.design(spec.run_dir, spec.design, baseline.doe)

    def _require_run(self) -> TrainedRun:
        if self.run is None:
            raise EdofprojError("this method needs a trained run (its DOE or its network); none was given")
        return self.run

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
                    f"method {spec.name} needs a trained run of its own, and there is none at '{path}': train one "
                    f"(edofproj train --config <config> --out {path} {hint}) or give --baselines, the folder that "
                    f"holds {spec.run_dir}/"
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

    def build_all(self, specs, progress: StageProgress, built: Sequence[PreparedMethod] = ()) -> list[PreparedMethod]:
        """Every method of ``specs`` that can be built here (the others leave a note), advancing ``progress``
        once per method; raises :class:`EdofprojError` when none can. ``built``: methods already built
        from the same run and optics (e.g. by its flat-screen evaluation), taken as they are instead of
        built again (their tuned filters, loaded networks and simulated PSFs with them)."""
        reuse = {method.name: method for method in built}
        prepared = []
        for spec in specs:
            method = reuse[spec.name] if spec.name in reuse else self.build(spec)
            if method is not None:
                prepared.append(method)
            progress.advance(1, detail=spec.name)
        if not prepared:
            raise EdofprojError("no method could be evaluated: " + "; ".join(self.notes))
        return prepared

    def build(self, spec: MethodSpec) -> PreparedMethod | None:
        """The method ``spec``, or None (with a note) when its separate run is missing or unsuitable, or when
        a classic element that was not asked for by name cannot be simulated with the run's optics (e.g. a
        pupil sampled too coarsely for its phase): then its design is dropped too."""
        if spec.optics not in CLASSIC_ELEMENTS or self.explicit:
            return self._build(spec)
        try:
            return self._build(spec)
        except EdofprojError as exc:
            self.designs.pop(spec.optics, None)
            self.notes.append(f"{spec.name} skipped: {exc}")
            return None

    def _build(self, spec: MethodSpec) -> PreparedMethod | None:
        baseline = self.baseline(spec) if spec.needs_separate_run else None
        if spec.needs_separate_run and baseline is None:
            return None
        if spec.optics == "lens":
            design = self.lens()
        elif spec.optics == "run":
            design = self.run_design()
        elif spec.optics in CLASSIC_ELEMENTS:
            design = self.classic_design(spec.optics)
        else:
            if baseline is None:
                raise EdofprojError(f"method {spec.name}: optics '{spec.optics}' needs a separate run")
            design = self.baseline_design(spec, baseline)
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
            source = baseline if baseline is not None else self._require_run()
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


def build_method(
    run_dir: str | Path,
    name: str = OURS,
    baselines_dir: str | Path | None = None,
    device: str | torch.device = "cpu",
) -> PreparedMethod:
    """The method ``name`` of the trained run in ``run_dir`` (a path or ``builtin:NAME``), built as
    ``evaluate`` builds it; a baseline's separate run is looked for in ``baselines_dir`` (default: the
    run's parent directory). One-line errors for an unknown name, a missing run or one that does not fit."""
    spec = method_spec(name)  # an unknown name fails before the run is loaded
    path = require_trained_run(run_dir)
    run = load_run(path)
    baselines = Path(baselines_dir) if baselines_dir is not None else path.parent
    method = MethodBuilder(run, run.cfg, baselines, explicit=True, device=device).build(spec)
    if method is None:  # explicit: a missing baseline raised already
        raise EdofprojError(f"method {name} could not be built from '{run_dir}'")
    return method
