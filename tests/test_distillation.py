"""Distillation (train.teacher): the term's closed form, the frozen teacher, the refusals, and the
term entering the training loss with its weight."""

import pytest
import torch

from edofproj.config import ConfigError, load_config
from edofproj.doe import build_run_doe
from edofproj.errors import EdofprojError
from edofproj.training.distillation import Teacher, distillation_term, load_teacher, same_design

REFERENCE = "builtin:cpu-doe-unet"  # a U-Net teacher with a linear base filter


def test_the_term_is_the_mean_absolute_difference_of_the_emitted_images():
    """``mean|clamp(x, 0, 1) - x_T|``: a student value beyond the range counts as the range's edge,
    and where it is clamped it gets no gradient."""
    student = torch.tensor([[[[-0.5, 0.2], [0.9, 1.7]]]], requires_grad=True)
    taught = torch.tensor([[[[0.1, 0.2], [0.5, 1.0]]]])
    term = distillation_term(student, taught)
    assert float(term.detach()) == pytest.approx((0.1 + 0.0 + 0.4 + 0.0) / 4)
    term.backward()
    assert student.grad is not None
    assert student.grad.flatten().tolist() == pytest.approx([0.0, 0.0, 0.25, 0.0])  # |.|' = 0 at 0 (torch's sign)
    assert float(distillation_term(taught, taught)) == 0.0


def test_the_teacher_is_frozen_and_emits_the_projector_range():
    class Doubling(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.scale = torch.nn.Parameter(torch.tensor(2.0))

        def forward(self, target, captured):
            return self.scale * target - captured

    teacher = Teacher(Doubling(), "doubling")
    target = torch.tensor([[[[0.1, 0.4, 0.8]]]])
    emitted = teacher(target, torch.zeros_like(target))
    torch.testing.assert_close(emitted, torch.tensor([[[[0.2, 0.8, 1.0]]]]))
    assert not emitted.requires_grad and not any(p.requires_grad for p in teacher.parameters())


def test_a_teacher_needs_the_runs_fixed_doe():
    """The teacher's DOE must be the student's: the same file is accepted; a DOE being trained,
    another design and a negative weight are refused with one line."""
    same = load_config("realtime", [f"doe.path={REFERENCE}", f"train.teacher={REFERENCE}"])
    doe = build_run_doe(same)
    teacher = load_teacher(same, doe, False, torch.device("cpu"), "none")
    assert teacher is not None and teacher.label == REFERENCE and same_design(doe, build_run_doe(same))

    with pytest.raises(EdofprojError, match="trains its DOE"):
        load_teacher(same, doe, True, torch.device("cpu"), "none")
    other = load_config("realtime", ["doe.kind=cubic", f"train.teacher={REFERENCE}"])
    other_doe = build_run_doe(other)
    assert not same_design(doe, other_doe)
    with pytest.raises(EdofprojError, match="another DOE"):
        load_teacher(other, other_doe, False, torch.device("cpu"), "none")
    assert load_teacher(load_config("realtime", [f"doe.path={REFERENCE}"]), doe, False, "cpu", "none") is None
    with pytest.raises(EdofprojError, match="at least 34x34"):  # the teacher's linear filter's reach
        load_teacher(
            load_config("realtime", [f"doe.path={REFERENCE}", f"train.teacher={REFERENCE}", "data.crop=32"]),
            doe,
            False,
            "cpu",
            "none",
        )
    with pytest.raises(ConfigError, match="teacher_weight"):
        load_config("realtime", ["train.teacher_weight=-1"])


@pytest.mark.slow
def test_the_term_enters_the_training_loss_with_its_weight(tmp_path):
    """One training step of the real-time network on the reference model's DOE with the reference
    model as teacher: the same step (same crops, depths and start) logs a loss that grows linearly
    in ``train.teacher_weight``, by a positive term below 1 (a mean absolute difference of images)."""
    from edofproj.runs.log import read_log
    from edofproj.training.trainer import train

    losses = {}
    for weight in (0.0, 1.0, 2.0):
        cfg = load_config(
            "realtime",
            [
                f"doe.path={REFERENCE}",
                f"train.teacher={REFERENCE}",
                f"train.teacher_weight={weight}",
                "train.steps=1",
                "train.warmup_steps=0",  # the logged loss is the step's, before its update
                "train.threads=1",
                "train.psf_table_depths=8",
                "data.crop=48",
                "train.batch_size=2",
                "train.validate_every=0",
            ],
        )
        train(cfg, tmp_path / f"w{weight}", progress=False)
        losses[weight] = read_log(tmp_path / f"w{weight}" / "train_log.csv")[0]["loss"]
    term = losses[1.0] - losses[0.0]
    assert 0 < term < 1
    assert losses[2.0] - losses[0.0] == pytest.approx(2 * term, rel=1e-4)
