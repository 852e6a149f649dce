"""Run ``edofproj`` and kill the process with SIGKILL at a chosen step and phase of training.

    python tests/kill_at.py STEP PHASE -- train --out RUN ...

The fault tier uses it instead of a timer, so that where ``kill -9`` lands depends on the state of
the run, never on the speed of the machine. Phases of step ``STEP``:

* ``draw``: after the batch is drawn, before the forward pass;
* ``update``: after the optimizer update, before the step's log row;
* ``checkpoint``: half-way through writing ``step_STEP.pt`` (its temporary file holds half the bytes);
* ``last``: after ``step_STEP.pt``, half-way through writing ``last.pt``.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

PHASES = ("draw", "update", "checkpoint", "last")


def kill_now() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def write_half_then_kill(write, target) -> None:
    """Let ``write(path)`` write the whole file, keep its first half, and die."""
    write(target)
    data = Path(target).read_bytes()
    Path(target).write_bytes(data[: len(data) // 2])
    kill_now()


def install(step: int, phase: str) -> None:
    import torch

    from edofproj.runs import checkpoint
    from edofproj.training import trainer

    if phase == "draw":
        sample_images = trainer.sample_images

        def draw_then_die(source, seed, at_step, *args, **kwargs):
            images = sample_images(source, seed, at_step, *args, **kwargs)
            if at_step == step:
                kill_now()
            return images

        trainer.sample_images = draw_then_die
    elif phase == "update":
        train_step = trainer._Session.train_step

        def update_then_die(self):
            result = train_step(self)
            if self.step == step:
                kill_now()
            return result

        trainer._Session.train_step = update_then_die  # type: ignore[method-assign]
    elif phase == "checkpoint":
        save = torch.save

        def save_half_then_die(payload, target, *args, **kwargs):
            if isinstance(payload, dict) and payload.get("step") == step:
                write_half_then_kill(lambda path: save(payload, path, *args, **kwargs), target)
            return save(payload, target, *args, **kwargs)

        checkpoint.torch.save = save_half_then_die  # the module's torch is the torch module: patched for all
    elif phase == "last":
        copyfile = checkpoint.shutil.copyfile

        def copy_half_then_die(source, target, *args, **kwargs):
            if Path(source).name == checkpoint.step_name(step):
                write_half_then_kill(lambda path: copyfile(source, path, *args, **kwargs), target)
            return copyfile(source, target, *args, **kwargs)

        checkpoint.shutil.copyfile = copy_half_then_die
    else:
        raise SystemExit(f"unknown phase {phase!r} (known: {', '.join(PHASES)})")


def main(argv: list[str]) -> int:
    separator = argv.index("--")
    step, phase = int(argv[0]), argv[1]
    install(step, phase)
    from edofproj.cli import main as edofproj_main

    return edofproj_main(argv[separator + 1 :])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
