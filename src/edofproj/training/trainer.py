"""Joint end-to-end training of the DOE and the compensation network (paper Sec. 3, Fig. 2).

One step, for a global batch of ``B`` training crops ``I_i``:

1. draw a screen depth per crop, ``z_i ~ U(z_min, z_max)`` (:mod:`.sampling`);
2. simulate the RGB PSFs of the current quantized DOE at all ``z_i`` in one call
   (straight-through quantizer, so the DOE's parameters get gradients), or look them up
   in a precomputed table for a fixed DOE (:mod:`.psf_table`);
3. render ``I*_i = project(I_i, P_i)`` (each sample its own PSF), observe it with the camera
   model, compensate ``Î_i = net(I_i, I*_i)`` and project again, ``Î*_i = project(clamp(Î_i), P_i)``
   (:mod:`.end_to_end`); with ``net.surface_input`` each crop also gets a random textured surface
   (:class:`~edofproj.data.textures.TrainingSurfaces`), the screen shows ``s ⊙ project(·) + a``, the
   network takes ``(s, a)`` and the crop is replaced by its goal in the surface's range
   (:func:`~edofproj.compensation.achievable.achievable_goal`), which the loss then compares with;
4. minimize ``L = (1/B) sum_i [alpha MSE(Î*_i, I_i) + beta D(Î*_i, I_i)]`` (Eq. 12) with Adam:
   the DOE at ``lr_optics``, the network at ``lr_net``, both decayed as

       lr(t) = lr_0 * f^(t / T)      (f = train.lr_final_fraction, T = train.steps),

   after clipping the DOE's and the network's gradient norms (each) to ``train.grad_clip``.

With ``train.refit_steps`` a run has a second phase, a fresh network for the DOE the first found
(:mod:`.phases`); the steps above are each phase's, the run's files count on across them.

Runs are deterministic under ``train.seed`` and resume exactly from a checkpoint
(:mod:`.checkpoint`), in either phase. Under ``torchrun`` the same code runs data-parallel (:mod:`.distributed`):
each process draws its share of the global batch, and DistributedDataParallel averages the
gradients. Only rank 0 writes files. A non-finite loss or gradient stops the run with a
one-line error naming the step; the last good checkpoint is kept.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import random
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from ..compensation.achievable import achievable_goal
from ..compensation.registry import build_network
from ..compensation.wiener import depth_ensemble_wiener_kernel
from ..config import Config, to_dict
from ..data import build_training_source
from ..data.textures import TrainingSurfaces
from ..doe import build_run_doe, load_doe, save_doe
from ..errors import BlurExceedsWindowWarning, EdofprojError, RecoveryWarning
from ..fileio import remove_stale_temp_files
from ..imaging.depth_layers import layer_depths_m
from ..locking import directory_lock
from ..net_config import MultirateConfig
from ..optics.psf_bank import design_engine, simulator_from_config
from ..optics.radial_engine import warn_if_blur_exceeds_window
from ..runs import (
    CHECKPOINT_DIR,
    DOE_NAME,
    FIGURES_DIR,
    check_new_run_dir,
    check_resume_config,
    last_checkpoint_path,
    write_run_config,
)
from ..runs.checkpoint import (
    capture_rng_state,
    load_newest_intact_checkpoint,
    load_state_checked,
    restore_rng_state,
    save_checkpoint,
)
from ..runs.figures import plot_doe_profile, plot_loss_curve, plot_psfs_across_depth
from ..runs.log import TrainingLog, read_log
from .distillation import distillation_term, load_teacher
from .distributed import (
    ProcessGroup,
    average_across_processes,
    barrier,
    replica_max_difference,
    setup_process_group,
    teardown_process_group,
)
from .end_to_end import EndToEndProjector, SimulatedPSF, resolve_mixed_precision
from .losses import build_loss
from .phases import JOINT, Phase, training_phases
from .psf_table import DepthPSFTable
from .sampling import BatchShard, sample_depth_maps, sample_depths_m, sample_images, sample_noise, sample_surfaces
from .validation import StepChecks

#: Depths shown in ``figures/psf_depths.png``.
FIGURE_DEPTHS = 6


@dataclass
class TrainingResult:
    """What a call of :func:`train` did: steps ``start_step -> step``, the last loss, total seconds,
    on a CUDA device the peak GPU memory PyTorch allocated in this session (bytes; None on the CPU), and
    whether the session ended at its time budget (:class:`TimeBudget`) before the run's end."""

    run_dir: Path
    start_step: int
    step: int
    loss: float
    seconds: float
    peak_gpu_memory_bytes: int | None = None
    stopped_at_time_budget: bool = False


# ----------------------------------------------------------------------------- building blocks


def doe_is_trained(cfg: Config, doe: nn.Module) -> bool:
    """The DOE is optimized when ``train.train_doe`` and it has trainable parameters (mlp, free)."""
    return bool(cfg.train.train_doe) and any(p.requires_grad for p in doe.parameters())


def build_psf_source(cfg: Config, doe: nn.Module, trained: bool, device) -> nn.Module:
    """A :class:`SimulatedPSF` for a DOE being optimized, a :class:`DepthPSFTable` for a fixed one."""
    simulator = simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine), device=device)
    z_min, z_max = cfg.psf.depth_min_m, cfg.psf.depth_max_m
    warn_if_blur_exceeds_window(simulator.geometry, np.array([z_min, z_max]), simulator.window)
    if trained:
        return SimulatedPSF(doe, simulator)
    for p in doe.parameters():
        p.requires_grad_(False)
    return DepthPSFTable.simulate(simulator, doe, z_min, z_max, cfg.train.psf_table_depths)


def start_from_wiener(cfg: Config, net: nn.Module, psf_source: nn.Module) -> None:
    """A network with a linear path (``initialize_linear_path``, the multirate network) trained for
    a *fixed* DOE starts that path as the depth-ensemble Wiener filter of the DOE's PSF table
    (``net.init_nsr`` > 0), cut to the ``(2s + 1)^2`` taps its local filter spans (``s = net.block_px``).
    With ``net.linear_path: fixed`` that path is then frozen: for a DOE being trained it is set, and
    then kept, to the current DOE's filter by :func:`~.linear_filter.refresh_linear_base` (before the
    first step and every ``train.linear_every`` steps). A resumed run then loads its checkpoint over
    this start."""
    initialize_linear_path = getattr(net, "initialize_linear_path", None)
    options = cfg.net
    if not isinstance(options, MultirateConfig) or initialize_linear_path is None:
        return
    if options.init_nsr > 0 and isinstance(psf_source, DepthPSFTable):
        kernels = depth_ensemble_wiener_kernel(
            psf_source.psf.detach().cpu().numpy(), options.init_nsr, radius=options.block_px
        )
        initialize_linear_path(kernels)
    if options.linear_path == "fixed":  # only the non-linear part trains (bounded around it in the safe form)
        for part in ("local_filter", "correction_to_pixels", "prefilter"):
            for p in net.get_submodule(part).parameters():
                p.requires_grad_(False)


def exponential_decay(total_steps: int, final_fraction: float, warmup_steps: int = 0):
    """``t -> min(1, (t + 1) / W) f^(t / T)``: the learning-rate multiplier after ``t`` of ``T``
    steps, with a linear warm-up over the first ``W`` steps (none for ``W = 0``). The warm-up keeps
    Adam's first steps (about ``lr`` per parameter whatever the gradient) from undoing a network
    that starts as a good compensation (``start_from_wiener``)."""
    warmup = max(int(warmup_steps), 0)
    return lambda t: min(1.0, (t + 1) / warmup if warmup else 1.0) * final_fraction ** (t / total_steps)


def loss_terms(
    loss_fn, cfg: Config, projected: torch.Tensor, target: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(loss, mse, perceptual)``: the objective ``alpha mse + beta perceptual`` and its two
    unweighted terms, from :meth:`~edofproj.training.losses.CompensationLoss.terms`
    (``perceptual`` is ``nan`` when the loss has no perceptual term)."""
    terms = loss_fn.terms(projected, target)
    perceptual = terms["perceptual"].detach()
    if not (cfg.loss.beta > 0 and cfg.loss.perceptual != "none"):
        perceptual = torch.full_like(perceptual, math.nan)
    return terms["total"], terms["mse"].detach(), perceptual


def seed_everything(seed: int) -> None:
    """Seed the global generators (network initialization; nothing else draws from them)."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)


def _clip(parameters: list[nn.Parameter], max_norm: float) -> torch.Tensor:
    """Clip the gradients' joint norm to ``max_norm`` (0: measure only); returns the norm before."""
    grads = [p for p in parameters if p.grad is not None]
    if not grads:
        return torch.zeros(())
    if max_norm > 0:
        return torch.nn.utils.clip_grad_norm_(grads, max_norm)
    return torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in grads]))


class TimeBudget:
    """A session's wall-clock budget: a step is begun only if it should end inside the budget.

    With ``t_0`` the clock when the session began, ``t`` now (before a step) and ``d`` the
    duration of the previous step (the time between the two checks before it and before this one:
    the step, its log row, its checkpoint and validation; 0 before the first), the session goes on
    while

        (t - t_0) + d <= seconds.

    ``seconds`` None: no budget. ``clock``: seconds of a monotonic clock (``time.monotonic``; a test
    gives its own). Under ``torchrun`` the processes stop together: at the first check where any of
    them would stop (one collective call per check, made only with a budget)."""

    def __init__(self, seconds: float | None, group: ProcessGroup, clock: Callable[[], float] = time.monotonic):
        if seconds is not None and not seconds > 0:
            raise EdofprojError(f"the time budget must be > 0 seconds, not {seconds}")
        self.seconds = seconds
        self.group = group
        self.clock = clock
        self.started = clock()
        self.previous: float | None = None
        self.reached = False

    def allows_another_step(self) -> bool:
        """Whether the next step should end inside the budget (always True without one); once False,
        :attr:`reached` stays True."""
        if self.seconds is None:
            return True
        now = self.clock()
        last_step_s = now - self.previous if self.previous is not None else 0.0
        self.previous = now
        stop = (now - self.started) + last_step_s > self.seconds
        if self.group.distributed:
            stop = bool(average_across_processes(torch.tensor([float(stop)]), self.group).item() > 0)
        self.reached = self.reached or stop
        return not stop


# ----------------------------------------------------------------------------- the training run


class _Session:
    """The state of one phase of a training session (one process): model, optimizer, data, files.
    ``phase``: which phase of the run (:mod:`.phases`; ``cfg`` is the phase's; None: a run of one phase);
    ``step`` counts the phase's steps, the run's files ``phase.offset + step``; checkpoints record the
    run's configuration ``run_cfg`` (default ``cfg``), as its ``config.yaml`` does."""

    def __init__(
        self, cfg: Config, run_dir: Path, group: ProcessGroup, phase: Phase | None = None, run_cfg: Config | None = None
    ):
        phase = phase if phase is not None else Phase(JOINT, cfg, 0, False)
        self.cfg = cfg
        self.run_cfg = run_cfg if run_cfg is not None else cfg
        self.phase = phase
        self.run_dir = run_dir
        self.group = group
        device = group.device
        seed_everything(cfg.train.seed)

        if phase.doe_from_run:  # the DOE the first phase fabricated, frozen
            self.doe = load_doe(run_dir / DOE_NAME).to(device)
        else:
            self.doe = build_run_doe(cfg).to(device)
        self.doe_trained = doe_is_trained(cfg, self.doe)
        self.net = build_network(cfg.net).to(device)
        if not cfg.train.train_net:
            for p in self.net.parameters():
                p.requires_grad_(False)
        psf_source = build_psf_source(cfg, self.doe, self.doe_trained, device).to(device)
        start_from_wiener(cfg, self.net, psf_source)
        self.checks = StepChecks(cfg, self.net, psf_source, run_dir, group.is_main, device, phase.offset)
        layers_m = None
        if cfg.train.screens == "varying":
            layers_m = layer_depths_m(cfg.psf.depth_min_m, cfg.psf.depth_max_m, max(2, cfg.imaging.depth_layers))
        mixed_precision = resolve_mixed_precision(cfg.train.mixed_precision, device)
        self.model = EndToEndProjector(
            psf_source, self.net, cfg.train.noise_sigma, cfg.train.quantize_capture, mixed_precision, layers_m
        )
        self.teacher = load_teacher(cfg, self.doe, self.doe_trained, device, mixed_precision)

        self.doe_params = [p for p in self.doe.parameters() if p.requires_grad]
        self.net_params = [p for p in self.net.parameters() if p.requires_grad]
        groups = []
        if self.doe_params:
            groups.append({"params": self.doe_params, "lr": cfg.train.lr_optics, "name": "doe"})
        if self.net_params:
            groups.append({"params": self.net_params, "lr": cfg.train.lr_net, "name": "net"})
        if not groups:
            raise EdofprojError(
                "nothing to train: the DOE is fixed (train.train_doe=false or a fixed design) and train.train_net=false"
            )
        self.optimizer = torch.optim.Adam(groups)
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, exponential_decay(cfg.train.steps, cfg.train.lr_final_fraction, cfg.train.warmup_steps)
        )
        self.loss_fn = build_loss(cfg.loss)
        if hasattr(self.loss_fn, "to"):
            self.loss_fn = self.loss_fn.to(device)
        self.source = build_training_source(cfg.data, cfg.train.seed)
        self.surfaces = TrainingSurfaces() if cfg.net.surface_input else None
        self.shard = BatchShard.for_rank(cfg.train.batch_size, group.rank, group.world_size)

        self.step = 0
        self.elapsed = 0.0
        self.last_checkpoint_step = phase.offset  # a later phase starts from the last one's final checkpoint
        self.wrapped: nn.Module = self.model
        if group.distributed:
            # buffers (a PSF table) are identical on every rank: no need to sync them each step
            no_buffer_sync: dict[str, Any] = (
                {"forward_sync_buffers": False}
                if "forward_sync_buffers" in inspect.signature(DistributedDataParallel).parameters
                else {"broadcast_buffers": False}
            )
            self.wrapped = DistributedDataParallel(
                self.model, device_ids=[device] if device.type == "cuda" else None, **no_buffer_sync
            )

    # -- checkpoints ---------------------------------------------------------------
    @property
    def run_step(self) -> int:
        """The run's step (the phase's plus the steps of the phases before)."""
        return self.phase.offset + self.step

    def state(self) -> dict:
        return {
            "step": self.run_step,
            "phase": self.phase.name,
            "phase_step": self.step,
            "elapsed_seconds": self.elapsed,
            "doe": self.doe.state_dict() if self.doe_trained else {},
            "net": self.net.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "rng": capture_rng_state(),
            "world_size": self.group.world_size,
            "process_group": self.group.backend,
            "config": to_dict(self.run_cfg),
            "sampling": "per-sample generators seeded by (train.seed, step, global index, stream)",
        }

    def restore(self, checkpoint: dict) -> None:
        if self.doe_trained:
            load_state_checked(self.doe, checkpoint.get("doe", {}), "the checkpoint's DOE")
        load_state_checked(self.net, checkpoint.get("net", {}), "the checkpoint's network")
        try:
            self.optimizer.load_state_dict(checkpoint["optimizer"])
            self.scheduler.load_state_dict(checkpoint["scheduler"])
        except (RuntimeError, KeyError, ValueError) as exc:
            raise EdofprojError(f"the checkpoint does not fit this run's model: {str(exc).splitlines()[0]}") from None
        restore_rng_state(checkpoint["rng"])
        self.step = int(checkpoint.get("phase_step", checkpoint["step"]))
        self.elapsed = float(checkpoint["elapsed_seconds"])
        self.last_checkpoint_step = self.run_step

    def save(self) -> None:
        """Checkpoint (and the current fabricated DOE), written by rank 0 after checking that all
        data-parallel replicas still hold identical parameters (a collective call)."""
        difference = replica_max_difference(list(self.model.parameters()), self.group)
        if difference != 0.0:
            raise EdofprojError(
                f"data-parallel replicas diverged at step {self.run_step} (parameters differ by up to {difference:.3g})"
            )
        if self.group.is_main:
            state = dict(self.state(), replica_max_difference=difference)
            save_checkpoint(self.run_dir / CHECKPOINT_DIR, state, keep=self.cfg.train.keep_checkpoints)
            if self.doe_trained:
                self.save_doe()
        self.last_checkpoint_step = self.run_step

    def save_doe(self) -> None:
        if self.cfg.doe.kind != "lens":
            save_doe(self.doe, self.run_dir / DOE_NAME, samples=self.cfg.psf.pupil_samples)

    # -- one optimizer step --------------------------------------------------------
    def train_step(self) -> tuple[float, float, float]:
        """One step on the global batch; returns (loss, mse, perceptual) averaged over the processes."""
        cfg, step = self.cfg, self.step + 1
        device = self.group.device
        if cfg.train.screens == "varying":
            depths = sample_depth_maps(
                cfg.train.seed,
                step,
                self.shard,
                cfg.data.crop,
                cfg.psf.depth_min_m,
                cfg.psf.depth_max_m,
            )
        else:
            depths = sample_depths_m(
                cfg.train.seed,
                step,
                self.shard,
                cfg.psf.depth_min_m,
                cfg.psf.depth_max_m,
                cfg.train.depth_sampling,
                cfg.train.depth_spacing,
            )
        images = sample_images(self.source, cfg.train.seed, step, self.shard, cfg.data.crop).to(device)
        surface: tuple[torch.Tensor, ...] = ()
        if self.surfaces is not None:  # net.surface_input: a textured surface per sample, the goal in its range
            reflectance, ambient = sample_surfaces(self.surfaces, cfg.train.seed, step, self.shard, cfg.data.crop)
            surface = (reflectance.to(device), ambient.to(device))
            images = achievable_goal(images, *surface).image
        noise = None
        if cfg.train.noise_sigma > 0:
            noise = sample_noise(cfg.train.seed, step, self.shard, tuple(images.shape[1:])).to(device)

        self.model.train()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BlurExceedsWindowWarning)  # warned once at the start
            out = self.wrapped(images, depths, noise, *surface)
        loss, mse, perceptual = loss_terms(self.loss_fn, cfg, out.projected, images)
        if self.teacher is not None:  # train.teacher: imitate its projector image (distillation.py)
            taught = self.teacher(images, out.captured)
            loss = loss + cfg.train.teacher_weight * distillation_term(out.compensated, taught)
        logged = average_across_processes(torch.stack([loss.detach(), mse, perceptual]).float().cpu(), self.group)
        if not math.isfinite(float(logged[0])):
            self._stop_non_finite(self.phase.offset + step, "loss", float(logged[0]))

        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        norms = [_clip(params, cfg.train.grad_clip) for params in (self.doe_params, self.net_params) if params]
        if not all(math.isfinite(float(n)) for n in norms):
            self._stop_non_finite(self.phase.offset + step, "gradient", math.nan)
        self.optimizer.step()
        self.scheduler.step()
        self.step = step
        return float(logged[0]), float(logged[1]), float(logged[2])

    def _stop_non_finite(self, step: int, what: str, value: float) -> None:
        where = (
            f"the last good checkpoint is step {self.last_checkpoint_step} ({last_checkpoint_path(self.run_dir)})"
            if self.last_checkpoint_step
            else "no checkpoint was written"
        )
        raise EdofprojError(f"training stopped: the {what} became {value} at step {step}; {where}")

    def current_lr(self) -> float:
        named = {g.get("name"): g["lr"] for g in self.optimizer.param_groups}
        lr = named.get("net", named.get("doe"))
        if lr is None:
            raise EdofprojError("the optimizer has neither a 'net' nor a 'doe' parameter group")
        return float(lr)

    # -- end-of-session files ------------------------------------------------------
    def figure_psfs(self) -> tuple[np.ndarray, torch.Tensor]:
        """The depths of the PSF figure and the PSFs there (the whole training range)."""
        depths = np.linspace(self.cfg.psf.depth_min_m, self.cfg.psf.depth_max_m, FIGURE_DEPTHS)
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore", BlurExceedsWindowWarning)
            return depths, self.model.psf_source(depths)

    def check_before_writing(self) -> None:
        """Compute once, before any file is written, the PSFs the steps and the figures will need:
        a sampling the simulation refuses (:class:`~edofproj.errors.SamplingError`) then stops the
        command with nothing written, instead of after a step or after the last one."""
        self.figure_psfs()

    def write_figures(self) -> None:
        figures = self.run_dir / FIGURES_DIR
        figures.mkdir(parents=True, exist_ok=True)
        plot_loss_curve(read_log(self.run_dir / "train_log.csv"), figures / "loss.png")
        plot_doe_profile(self.doe, figures / "doe_profile.png", samples=self.cfg.psf.pupil_samples)
        depths, psf = self.figure_psfs()
        plot_psfs_across_depth(psf, depths, figures / "psf_depths.png")


def train(
    cfg: Config,
    out_dir: str | Path,
    resume: bool = False,
    stop_after: int | None = None,
    progress: bool = True,
    time_budget_s: float | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> TrainingResult:
    """Train (or, with ``resume``, continue) the run in ``out_dir`` through all its phases
    (:func:`~.phases.total_steps`: ``train.steps``, plus ``train.refit_steps`` of a second phase).

    ``stop_after``: end this session after that many steps of the run in total (the learning-rate
    schedules still span their phases), e.g. to train in chunks; ``time_budget_s``: end it before
    the first step that would end more than that many seconds after this call (:class:`TimeBudget`,
    read on ``clock``), e.g. to fit a lease of a machine; a checkpoint is written at the end of
    every session, so ``resume`` continues it exactly. Resuming with a larger ``train.steps`` during the first
    phase (or ``train.refit_steps`` during the second) extends that phase; the remaining learning
    rates then follow ``lr_0 f^(t / T)`` with the new ``T``.
    Returns a :class:`TrainingResult`.
    """
    run_dir = Path(out_dir)
    if resume and not run_dir.is_dir():
        raise EdofprojError(f"--resume: the run directory '{run_dir}' does not exist")
    if cfg.train.threads > 0:
        torch.set_num_threads(cfg.train.threads)
    group = setup_process_group(cfg.train.device)
    try:
        # rank 0 writes the run directory: it holds the directory's lock while it runs
        lock = directory_lock(run_dir, "edofproj train", "--out") if group.is_main else contextlib.nullcontext()
        with lock:
            budget = TimeBudget(time_budget_s, group, clock)
            return _train(cfg, run_dir, resume, stop_after, progress, group, budget)
    finally:
        teardown_process_group(group)


def remove_interrupted_writes(run_dir: Path) -> None:
    """Delete the temporary files that a killed session left in the (locked) run directory."""
    removed = remove_stale_temp_files(run_dir, recursive=True)
    if removed:
        names = ", ".join(str(p.relative_to(run_dir)) for p in removed[:3])
        more = f" and {len(removed) - 3} more" if len(removed) > 3 else ""
        warnings.warn(
            f"removed {len(removed)} temporary file(s) of interrupted writes from '{run_dir}': {names}{more}",
            RecoveryWarning,
            stacklevel=2,
        )


def checkpoint_phase(phases: list[Phase], checkpoint: dict) -> int:
    """The index of the phase a checkpoint was written in (a checkpoint without phase: the first); a
    one-line error when it is none of ``phases`` (the run's phases changed, e.g. ``train.steps`` after the
    first phase ended)."""
    name = checkpoint.get("phase", phases[0].name)
    offset = int(checkpoint["step"]) - int(checkpoint.get("phase_step", checkpoint["step"]))
    for index, phase in enumerate(phases):
        if phase.name == name and phase.offset == offset:
            return index
    raise EdofprojError(
        f"--resume: the run's checkpoint is step {checkpoint['step']} of its {name} phase, which began after step "
        f"{offset}; with this configuration the phases are "
        + ", ".join(f"{p.name} (steps {p.offset + 1}-{p.end})" for p in phases)
        + ": keep train.steps as the run was trained"
    )


def _train(
    cfg: Config,
    run_dir: Path,
    resume: bool,
    stop_after: int | None,
    progress: bool,
    group: ProcessGroup,
    budget: TimeBudget,
) -> TrainingResult:
    if resume:
        check_resume_config(run_dir, cfg)
        if group.is_main:
            remove_interrupted_writes(run_dir)
        checkpoints = run_dir / CHECKPOINT_DIR
        if not last_checkpoint_path(run_dir).is_file() and not any(checkpoints.glob("step_*.pt")):
            # the run stopped before its first checkpoint (its config matches): nothing to lose, start over
            warnings.warn(
                f"--resume: '{run_dir}' stopped before its first checkpoint: training it from step 0",
                RecoveryWarning,
                stacklevel=2,
            )
            checkpoint = None
        else:
            checkpoint, _ = load_newest_intact_checkpoint(checkpoints)
    else:
        check_new_run_dir(run_dir)
        checkpoint = None
    barrier(group)

    phases = training_phases(cfg)
    first = checkpoint_phase(phases, checkpoint) if checkpoint is not None else 0
    total = phases[-1].end
    end = total if stop_after is None else min(total, int(stop_after))
    start = int(checkpoint["step"]) if checkpoint is not None else 0

    session = _Session(phases[first].cfg, run_dir, group, phases[first], cfg)
    session.check_before_writing()
    if checkpoint is not None:
        session.restore(checkpoint)
    session.checks.start(session.step, resumed=checkpoint is not None)
    if group.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_run_config(run_dir, cfg)
        if not session.doe_trained and not session.phase.doe_from_run and start == 0:
            session.save_doe()
    if end <= start:
        return TrainingResult(run_dir, start, start, math.nan, session.elapsed)

    log = TrainingLog(run_dir, resume_step=start) if group.is_main else None
    bar = None
    if group.is_main and progress:
        bar = tqdm(total=end, initial=start, unit="step", dynamic_ncols=True, desc=cfg.name)
    loss = math.nan
    try:
        for index in range(first, len(phases)):
            phase = phases[index]
            if index > first:
                if phase.offset >= end or budget.reached:
                    break
                elapsed = session.elapsed  # the run's training seconds go on across the phases
                del session  # free the last phase's model before building this one's
                barrier(group)  # rank 0 has written the DOE file this phase reads
                session = _Session(phase.cfg, run_dir, group, phase, cfg)
                session.elapsed = elapsed
                session.checks.start(0, resumed=False)
            if bar is not None and len(phases) > 1:
                bar.set_description(f"{cfg.name} ({phase.name})")
            phase_end = min(phase.cfg.train.steps, end - phase.offset)
            loss = _train_phase(session, phase_end, log, bar, budget) if session.step < phase_end else loss
    finally:
        if bar is not None:
            bar.close()
        if log is not None:
            log.close()
    if group.is_main:
        session.write_figures()
    barrier(group)
    peak = torch.cuda.max_memory_allocated(group.device) if group.device.type == "cuda" else None
    stopped = budget.reached and session.run_step < total
    return TrainingResult(run_dir, start, session.run_step, loss, session.elapsed, peak, stopped)


def _train_phase(session: _Session, end: int, log: TrainingLog | None, bar, budget: TimeBudget) -> float:
    """Steps ``session.step + 1 .. end`` of the session's phase, logged and checkpointed (a checkpoint after
    the last, or after the last that ``budget`` allowed); returns the last loss."""
    cfg = session.cfg
    loss = math.nan
    clock = time.perf_counter()
    base_elapsed = session.elapsed
    while session.step < end:
        if not budget.allows_another_step():
            if session.last_checkpoint_step != session.run_step:
                session.save()
            break
        lr = session.current_lr()
        loss, mse, perceptual = session.train_step()
        session.elapsed = base_elapsed + time.perf_counter() - clock
        if log is not None:
            log.write(session.run_step, loss, mse, perceptual, lr, session.elapsed)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{loss:.4g}")
        session.checks.after_step(session.step, tqdm.write if bar is not None else print)
        if session.step % cfg.train.checkpoint_every == 0 or session.step == end:
            session.save()
    return loss
