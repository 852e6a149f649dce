"""A loan of a GPU machine cannot be wasted: training ends at a time budget with a checkpoint, and the
run the loan script packs into its OUT continues in the next loan bit for bit.

The time budget is checked on a fake clock that the training steps themselves advance (so the
tests wait for a state, never for a clock); the loan script (``benchmarks/gpu/loan.py``) runs on the
CPU with a tiny configuration, twice: a first loan that trains 3 of 6 steps, then a second that
resumes its pack from a fresh folder, against 6 steps trained straight.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import shutil
from pathlib import Path

import pytest
import torch

from edofproj.cli import main as cli_main
from edofproj.config import Config, apply_overrides, dump_config, load_config
from edofproj.errors import EdofprojError
from edofproj.runs import saved_config
from edofproj.runs.checkpoint import load_checkpoint
from edofproj.runs.pack import read_manifest, unpack_run
from edofproj.training import trainer as trainer_module
from edofproj.training.distributed import ProcessGroup
from edofproj.training.trainer import TimeBudget, train
from tiny_configs import TINY_EVALUATION, TINY_TRAINING

GPU = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu"
COMPARED = ("step", "doe", "net", "optimizer", "scheduler")


def assert_same_state(a, b, path=""):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same_state(a[key], b[key], f"{path}/{key}")
    elif torch.is_tensor(a):
        assert torch.equal(a, b), path
    else:
        assert a == b, path


def losses(run: Path) -> list[tuple[str, str]]:
    with (run / "train_log.csv").open(newline="") as handle:
        return [(row["step"], row["loss"]) for row in csv.DictReader(handle)]


class FakeClock:
    """Seconds that pass only when a training step is taken (``step_s`` per step)."""

    def __init__(self, step_s: float):
        self.now = 0.0
        self.step_s = step_s

    def __call__(self) -> float:
        return self.now


def test_time_budget_stops_before_the_step_that_would_end_past_it():
    """``(t - t0) + d <= budget``: with steps of 10 s and 35 s, steps 1-3 run (they end at 10, 20, 30 s);
    a 4th would end at 40 s."""
    clock = FakeClock(10.0)
    budget = TimeBudget(35.0, ProcessGroup(), clock)
    taken = 0
    while budget.allows_another_step():
        clock.now += clock.step_s
        taken += 1
        assert taken < 100
    assert taken == 3 and budget.reached
    assert TimeBudget(None, ProcessGroup(), clock).allows_another_step()
    with pytest.raises(EdofprojError, match="must be > 0"):
        TimeBudget(0.0, ProcessGroup(), clock)


def test_train_time_budget_option_refuses_a_non_positive_or_non_finite_number(tmp_path, capsys):
    for value in ("0", "-5", "nan", "inf", "soon"):
        with pytest.raises(SystemExit) as exit_code:
            cli_main(["train", "--config", "cpu", "--out", str(tmp_path / "run"), "--time-budget", value])
        assert exit_code.value.code == 2
        assert "--time-budget" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


TINY = TINY_TRAINING + [
    "train.batch_size=2",
    "train.steps=8",
    "train.checkpoint_every=2",
    "train.keep_checkpoints=2",
    "train.psf_table_depths=16",
]


@pytest.mark.slow  # three trainings
def test_training_ends_at_its_time_budget_with_a_checkpoint_and_resumes_bit_for_bit(tmp_path, monkeypatch):
    cfg = apply_overrides(Config(), TINY)
    straight = train(cfg, tmp_path / "straight", progress=False)
    assert (straight.step, straight.stopped_at_time_budget) == (8, False)

    clock = FakeClock(10.0)
    step = trainer_module._Session.train_step

    def timed_step(session):
        result = step(session)
        clock.now += clock.step_s
        return result

    monkeypatch.setattr(trainer_module._Session, "train_step", timed_step)
    first = train(cfg, tmp_path / "budget", progress=False, time_budget_s=35.0, clock=clock)
    monkeypatch.undo()
    assert (first.start_step, first.step, first.stopped_at_time_budget) == (0, 3, True)
    # step 3 is not a checkpoint step (every 2): the session wrote one where it stopped
    assert load_checkpoint(tmp_path / "budget" / "checkpoints" / "last.pt")["step"] == 3

    second = train(cfg, tmp_path / "budget", resume=True, progress=False)
    assert (second.start_step, second.step, second.stopped_at_time_budget) == (3, 8, False)
    a = load_checkpoint(tmp_path / "straight" / "checkpoints" / "last.pt")
    b = load_checkpoint(tmp_path / "budget" / "checkpoints" / "last.pt")
    assert_same_state({k: a[k] for k in COMPARED}, {k: b[k] for k in COMPARED})
    assert losses(tmp_path / "straight") == losses(tmp_path / "budget")


def load_loan():
    spec = importlib.util.spec_from_file_location("loan", GPU / "loan.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_loan_sizes_the_pack_to_what_is_left_in_out(tmp_path):
    loan = load_loan()
    out = tmp_path / "out"
    out.mkdir()
    # 8 files less the manifest and record.json leave 6, but 64 MB less record.json's room only 4 of 16 MB
    room = loan.OUT_MAX_TOTAL_BYTES - loan.RECORD_BYTES
    assert loan.pack_room(out) == (4, room // 4)
    (out / "placement.log").write_bytes(b"x" * 30_000_000)
    (out / "results.tar.gz").write_bytes(b"x" * 1_000_000)
    parts, part_bytes = loan.pack_room(out)
    room = loan.OUT_MAX_TOTAL_BYTES - 31_000_000 - loan.RECORD_BYTES
    assert parts == 3 and part_bytes * parts <= room and part_bytes <= loan.OUT_MAX_FILE_BYTES
    for index in range(4):
        (out / f"other{index}.csv").write_text("1")
    assert loan.pack_room(out)[0] == 0


def test_loan_parses_its_options_and_keeps_its_work_outside_out(tmp_path):
    loan = load_loan()
    args = loan.parse_args([str(tmp_path / "out"), "--budget-s", "500", "--work", str(tmp_path / "work")])
    command = loan.train_command(tmp_path / "run", args, 321.4)
    assert command[command.index("--time-budget") + 1] == "321" and command[command.index("--config") + 1] == "paper"
    sets = [command[i + 1] for i, arg in enumerate(command) if arg == "--set"]
    assert sets == [*loan.LOAN_OVERRIDES, "train.device=cuda"]
    cfg = load_config("paper", sets)  # the loan's paper run is a configuration the trainer accepts
    assert (cfg.data.crop, cfg.train.batch_size, cfg.loss.perceptual) == (256, 4, "ms-ssim")
    with pytest.raises(SystemExit):
        loan.parse_args([str(tmp_path / "out"), "--budget-s", "5", "--work", str(tmp_path / "out" / "w")])


@pytest.mark.slow  # two loans on the CPU (trainings and an evaluation in subprocesses) and a straight training
def test_a_loan_packs_its_run_within_out_limits_and_the_next_loan_resumes_it_bit_for_bit(tmp_path, monkeypatch):
    loan = load_loan()
    cfg = apply_overrides(Config(), TINY_EVALUATION + ["train.steps=6", "train.checkpoint_every=4", "name=tiny"])
    (tmp_path / "tiny.yaml").write_text(dump_config(cfg))
    monkeypatch.chdir(tmp_path)
    common = ["--device", "cpu", "--no-loan-overrides", "--budget-s", "900", "--reserve-s", "200"]
    first = ["out1", "--config", "tiny.yaml", "--stop-after", "3", "--sets", "test", "--work", "work1", *common]
    assert loan.main(first) == 0
    out1 = tmp_path / "out1"
    files = sorted(p.name for p in out1.iterdir())
    assert files == ["record.json", "results.tar.gz", "run.pack.json", "run.tar.000"]
    assert all(p.stat().st_size <= loan.OUT_MAX_FILE_BYTES for p in out1.iterdir())

    record = json.loads((out1 / "record.json").read_text())
    assert record["training"]["step"] == 3 and record["pack"]["resumable"] is True
    table = record["evaluation"]["test"]["doe+net"]
    assert 0 < table["ssim_worst"] <= table["ssim_mean"] <= 1 and table["depths"] == 2
    assert read_manifest(out1 / "run.pack.json")["step"] == 3

    carried = tmp_path / "carried"  # the next loan's copy of the files that came back, nothing else
    shutil.copytree(out1, carried)
    shutil.rmtree(tmp_path / "work1")
    second = ["out2", "--resume", "carried/run.pack.json", "--sets", "", "--work", "work2", *common]
    assert loan.main(second) == 0
    unpack_run(tmp_path / "out2" / "run.pack.json", tmp_path / "back")

    straight = train(saved_config(tmp_path / "back"), tmp_path / "straight", progress=False)
    assert straight.step == 6
    a = load_checkpoint(tmp_path / "straight" / "checkpoints" / "last.pt")
    b = load_checkpoint(tmp_path / "back" / "checkpoints" / "last.pt")
    assert_same_state({k: a[k] for k in COMPARED}, {k: b[k] for k in COMPARED})
    assert losses(tmp_path / "straight") == losses(tmp_path / "back")


def test_a_loan_refuses_to_resume_a_slimmed_pack_and_still_writes_its_record(tmp_path):
    from edofproj.runs.pack import pack_run
    from test_runs_pack import fake_run

    loan = load_loan()
    packed = pack_run(fake_run(tmp_path / "run"), tmp_path / "carried", resumable=False)
    out = tmp_path / "out"
    argv = [str(out), "--resume", str(packed.manifest), "--budget-s", "300", "--work", str(tmp_path / "work")]
    assert loan.main([*argv, "--device", "cpu"]) == 1
    record = json.loads((out / "record.json").read_text())
    assert "not resumed" in record["errors"]["train"] and "training" not in record
    assert record["pack"] == {"refused": ["no checkpoint: nothing trained"]}
    assert sorted(p.name for p in out.iterdir()) == ["record.json", "results.tar.gz"]
