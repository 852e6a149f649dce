"""Distillation: a network learns from a trained run's network as well as from the loss.

A small network (the real-time multi-rate network) trained for a fixed DOE can be given a
*teacher*: the network of a trained run for the same DOE (the reference model's U-Net). Both see
the same target ``I`` and capture ``I*`` of each training crop, and the objective gains a term

    L = L_task(A(x), I) + w * mean| clamp(x, 0, 1) - clamp(x_T, 0, 1) |,    x_T = T(I, I*)

where ``x`` is the student's projector input, ``x_T`` the teacher's, ``clamp`` the projector's
range (what is emitted) and ``w`` ``train.teacher_weight``. The teacher's projector image is a
target the student can reach pixel by pixel, which the task loss, taken after the blur ``A``,
gives only through the blur. The teacher runs without gradients, in the precision of the student's
network (bfloat16 autocast where the training uses it).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..builtin_runs import run_label
from ..config import Config
from ..errors import EdofprojError
from ..runs import load_run


class Teacher(nn.Module):
    """The frozen network of a trained run: ``forward(target, captured) -> clamp(x_T, 0, 1)``,
    ``(B, C, H, W)`` each."""

    def __init__(self, net: nn.Module, label: str, mixed_precision: str = "none") -> None:
        super().__init__()
        self.net = net.eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.label = label
        self.mixed_precision = mixed_precision

    @torch.no_grad()
    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        with torch.autocast(target.device.type, dtype=torch.bfloat16, enabled=self.mixed_precision == "bf16"):
            emitted = self.net(target, captured)
        return emitted.float().clamp(0.0, 1.0)


def distillation_term(compensated: torch.Tensor, taught: torch.Tensor) -> torch.Tensor:
    """``mean|clamp(x, 0, 1) - x_T|`` of the student's projector input ``x`` and the teacher's emitted
    image ``x_T`` (already clamped), both ``(B, C, H, W)``: a scalar."""
    return (compensated.clamp(0.0, 1.0) - taught).abs().mean()


def _design_arrays(doe: nn.Module) -> dict[str, np.ndarray]:
    return {name: value.detach().cpu().numpy() for name, value in doe.state_dict().items()}


def same_design(a: nn.Module, b: nn.Module) -> bool:
    """Whether two DOEs hold the same parameters and buffers (the same fabricated design)."""
    first, second = _design_arrays(a), _design_arrays(b)
    return first.keys() == second.keys() and all(
        first[k].shape == second[k].shape and np.array_equal(first[k], second[k]) for k in first
    )


def load_teacher(cfg: Config, doe: nn.Module, doe_trained: bool, device, mixed_precision: str) -> Teacher | None:
    """The teacher of ``cfg.train.teacher`` on ``device``, or None when there is none.

    Refuses (one-line :class:`~edofproj.errors.EdofprojError`) a DOE being trained, a student or
    teacher that takes a textured surface, and a teacher trained for another DOE than ``doe``:
    its projector images would compensate other PSFs."""
    source = cfg.train.teacher
    if not source:
        return None
    if doe_trained:
        raise EdofprojError(
            "train.teacher needs a fixed DOE, the teacher's (doe.kind=file, doe.path=<the teacher run>): "
            "this run trains its DOE"
        )
    teacher_run = load_run(source)
    label = run_label(teacher_run.run_dir)
    if cfg.net.surface_input or teacher_run.cfg.net.surface_input:
        raise EdofprojError(f"train.teacher: networks that take a textured surface cannot be distilled ({label})")
    if not same_design(doe, teacher_run.doe):
        raise EdofprojError(f"train.teacher {label} was trained for another DOE than this run's: set doe.path={label}")
    teacher = Teacher(teacher_run.net, label, mixed_precision).to(device)
    crop = torch.zeros(1, 3, cfg.data.crop, cfg.data.crop, device=device)
    try:  # a crop the teacher cannot take (its linear filter's reach) stops the run before any file
        teacher(crop, crop)
    except EdofprojError as exc:
        raise EdofprojError(f"train.teacher {label}: {exc}") from None
    return teacher
