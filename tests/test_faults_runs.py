"""Fault tier: training runs under ``kill -9``, concurrent writers and damaged checkpoints (CLI subprocesses)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from edofproj.locking import LOCK_NAME, directory_lock
from tiny_configs import TINY_TRAINING

pytestmark = pytest.mark.slow  # CLI subprocesses that train

STEPS = 8
CONFIG = TINY_TRAINING + [
    f"train.steps={STEPS}",
    "train.checkpoint_every=1",
    "train.batch_size=1",
    "train.keep_checkpoints=0",
]


KILL_AT = Path(__file__).with_name("kill_at.py")


def _command(out: Path, *extra: str) -> list[str]:
    sets = [a for o in CONFIG for a in ("--set", o)]
    return [sys.executable, "-m", "edofproj.cli", "train", "--out", str(out), "--quiet", *sets, *extra]


def _env() -> dict:
    return dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(sys.path))


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, env=_env(), capture_output=True, text=True, timeout=300)


def _logged_steps(run: Path) -> int:
    log = run / "train_log.csv"
    return max(len(log.read_text().splitlines()) - 1, 0) if log.is_file() else 0


def _final_state(run: Path) -> dict:
    return torch.load(run / "checkpoints" / "last.pt", weights_only=True)


def _assert_same_run(run: Path, reference: Path) -> None:
    mine, theirs = _final_state(run), _final_state(reference)
    assert mine["step"] == theirs["step"] == STEPS
    for part in ("net", "doe"):
        assert mine[part].keys() == theirs[part].keys()
        for key in mine[part]:
            assert torch.equal(mine[part][key], theirs[part][key]), f"{part}.{key} differs"
    log, reference_log = (p / "train_log.csv" for p in (run, reference))
    losses = [line.split(",")[1] for line in log.read_text().splitlines()[1:]]
    reference_losses = [line.split(",")[1] for line in reference_log.read_text().splitlines()[1:]]
    assert losses == reference_losses


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("faults") / "reference"
    result = _run(_command(out))
    assert result.returncode == 0, result.stderr
    return out


#: Where each successive process of the run is killed: (step, phase) of tests/kill_at.py, in the order
#: of the run; phases cover the drawing of a batch, the update, and both files of a checkpoint.
KILLS = [(2, "draw"), (3, "checkpoint"), (3, "update"), (5, "last"), (7, "update")]


def test_kill_9_at_chosen_steps_and_phases_then_resume_ends_bit_identical(reference, tmp_path):
    """Each process dies by SIGKILL at a state of the run (tests/kill_at.py), not at a time, so the
    test does the same on a fast or a loaded machine; the last resume runs to the end."""
    run = tmp_path / "killed"
    args = _command(run)
    for step, phase in KILLS:
        proc = subprocess.run(
            [sys.executable, str(KILL_AT), str(step), phase, "--", *args[3:]],
            env=_env(),
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == -signal.SIGKILL, (step, phase, proc.stderr)
        args = _command(run, "--resume")
    result = _run(args)
    assert result.returncode == 0, result.stderr
    assert not (run / LOCK_NAME).exists()
    assert not [p for p in (run / "checkpoints").iterdir() if p.name.startswith(".")]  # no temp files left
    _assert_same_run(run, reference)


def test_two_trains_started_together_on_one_out_never_mix(reference, tmp_path):
    """Whichever starts writing first trains the run; the other is refused in one line (while the
    first writes: its lock; after: the run directory is not empty). The run is the reference's."""
    run = tmp_path / "contested"
    procs = [
        subprocess.Popen(_command(run), env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    results = [(p, p.communicate(timeout=300)[1]) for p in procs]
    codes = sorted(p.returncode for p, _ in results)
    assert codes == [0, 2], [err for _, err in results]
    refusal = next(err for p, err in results if p.returncode == 2).strip()
    assert refusal.count("\n") == 0
    # the lock's holder named, or (while it is still writing its name into the lock) "another edofproj process"
    assert (
        "is being written by edofproj train" in refusal
        or "is being written by another edofproj process" in (refusal)
        or "is not empty" in refusal
    )
    _assert_same_run(run, reference)


def test_a_train_on_a_locked_out_is_refused_naming_the_writer(tmp_path):
    run = tmp_path / "locked"
    with directory_lock(run, "edofproj train", "--out"):
        result = _run(_command(run))
    assert result.returncode == 2
    message = result.stderr.strip()
    assert message.count("\n") == 0
    assert f"--out '{run}' is being written by edofproj train (PID {os.getpid()} on host" in message
    assert not run.exists()  # the refused process wrote nothing; the released lock left nothing


def test_resume_removes_temp_files_and_falls_back_past_a_truncated_last_checkpoint(reference, tmp_path):
    run = tmp_path / "damaged"
    shutil.copytree(reference, run)
    checkpoints = run / "checkpoints"
    last = checkpoints / "last.pt"
    data = last.read_bytes()
    stale = checkpoints / ".last.pt.tmp-ab12cd34.pt"
    stale.write_bytes(data[: len(data) // 2])  # what kill -9 during a save leaves behind
    last.write_bytes(data[: len(data) // 3])
    (checkpoints / f"step_{STEPS:06d}.pt").write_bytes(b"")  # the newest step file is damaged too
    result = _run(_command(run, "--resume"))
    assert result.returncode == 0, result.stderr
    assert "removed 1 temporary file(s) of interrupted writes" in result.stderr
    assert f"last.pt' cannot be read (truncated or damaged): using 'step_{STEPS - 1:06d}.pt'" in result.stderr
    assert not stale.exists()
    _assert_same_run(run, reference)


def test_a_run_killed_before_its_first_checkpoint_resumes_from_step_0(reference, tmp_path):
    run = tmp_path / "early"
    shutil.copytree(reference, run)
    shutil.rmtree(run / "checkpoints")  # what a kill during step 1 leaves: config, log header, DOE
    (run / "train_log.csv").write_text("step,loss,mse,perceptual,lr,seconds\n")
    result = _run(_command(run, "--resume"))
    assert result.returncode == 0, result.stderr
    assert "stopped before its first checkpoint: training it from step 0" in result.stderr
    _assert_same_run(run, reference)


def test_a_garbage_checkpoint_is_refused_without_unsafe_advice(reference, tmp_path):
    run = tmp_path / "garbage"
    shutil.copytree(reference, run)
    generator = np.random.default_rng(7)
    for index, path in enumerate(sorted((run / "checkpoints").glob("*.pt"))):
        # fixed garbage; the first file starts like a pickle of protocol 229 (torch warns before it fails)
        head = b"\x80\xe5" if index == 0 else b""
        path.write_bytes(head + generator.integers(0, 256, 2000, dtype=np.uint8).tobytes())
    result = _run(_command(run, "--resume"))
    assert result.returncode == 2
    message = result.stderr.strip()
    assert message.count("\n") == 0 and "truncated, damaged or not an edofproj checkpoint" in message
    assert "weights_only" not in message


def test_a_file_that_looks_like_another_pickle_protocol_is_one_error_and_no_warning(tmp_path):
    """torch warns ("Detected pickle protocol ...") before failing on such a file; the user gets one line only."""
    import warnings

    from edofproj.errors import EdofprojError
    from edofproj.runs.checkpoint import load_checkpoint

    path = tmp_path / "step_000010.pt"
    path.write_bytes(b"\x80\xe5" + bytes(range(256)) * 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(EdofprojError, match="truncated, damaged or not an edofproj checkpoint"):
            load_checkpoint(path)
