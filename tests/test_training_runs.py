"""Training runs: exact resume, run-directory contents, refusals, non-finite loss, baselines, CLI."""

from __future__ import annotations

import csv
import shutil

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.compensation.registry import build_network
from edofproj.config import Config, apply_overrides, dump_config, load_config, to_dict
from edofproj.doe import build_run_doe, load_doe
from edofproj.errors import EdofprojError, RecoveryWarning
from edofproj.runs import load_run
from edofproj.runs.checkpoint import load_checkpoint
from edofproj.runs.log import COLUMNS
from edofproj.training import losses
from edofproj.training import trainer as trainer_module
from edofproj.training.trainer import seed_everything, train
from tiny_configs import TINY_TRAINING

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess


TINY = TINY_TRAINING + [
    "train.batch_size=2",
    "train.steps=8",
    "train.checkpoint_every=2",
    "train.keep_checkpoints=2",
    "train.psf_table_depths=16",
]


def tiny_config(*extra: str) -> Config:
    return apply_overrides(Config(), TINY + list(extra))


def _log_rows(run_dir):
    with open(run_dir / "train_log.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def _assert_same_state(a, b):
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(a[key], dict):
            _assert_same_state(a[key], b[key])
        elif torch.is_tensor(a[key]):
            assert torch.equal(a[key], b[key]), key
        else:
            assert a[key] == b[key], key


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("runs") / "straight"
    cfg = tiny_config()
    result = train(cfg, run_dir, progress=False)
    return cfg, run_dir, result


def test_resume_continues_bit_for_bit(straight_run, tmp_path):
    cfg, straight_dir, _ = straight_run
    run_dir = tmp_path / "chunked"
    first = train(cfg, run_dir, stop_after=4, progress=False)
    assert (first.start_step, first.step) == (0, 4)
    second = train(cfg, run_dir, resume=True, progress=False)
    assert (second.start_step, second.step) == (4, 8)
    a = load_checkpoint(straight_dir / "checkpoints" / "last.pt")
    b = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    for key in ("step", "doe", "net", "optimizer", "scheduler"):
        _assert_same_state({key: a[key]}, {key: b[key]})
    rows_a, rows_b = _log_rows(straight_dir), _log_rows(run_dir)
    assert [r["step"] for r in rows_b] == [str(s) for s in range(1, 9)]
    for ra, rb in zip(rows_a, rows_b):
        assert {k: v for k, v in ra.items() if k != "seconds"} == {k: v for k, v in rb.items() if k != "seconds"}
    assert np.array_equal(np.load(straight_dir / "doe.npz")["height_m"], np.load(run_dir / "doe.npz")["height_m"])


def test_resume_after_a_crash_drops_the_log_rows_past_the_checkpoint(straight_run, tmp_path):
    cfg, straight_dir, _ = straight_run
    crashed = tmp_path / "crashed"
    shutil.copytree(straight_dir, crashed)
    # as if the process died after step 8 was logged but before its checkpoint was written
    shutil.copyfile(crashed / "checkpoints" / "step_000006.pt", crashed / "checkpoints" / "last.pt")
    result = train(cfg, crashed, resume=True, progress=False)
    assert (result.start_step, result.step) == (6, 8)
    rows_a, rows_b = _log_rows(straight_dir), _log_rows(crashed)
    assert [r["step"] for r in rows_b] == [str(s) for s in range(1, 9)]
    assert [r["loss"] for r in rows_a] == [r["loss"] for r in rows_b]
    _assert_same_state(
        load_checkpoint(straight_dir / "checkpoints" / "last.pt")["net"],
        load_checkpoint(crashed / "checkpoints" / "last.pt")["net"],
    )


def test_a_different_seed_trains_differently(straight_run, tmp_path):
    cfg, straight_dir, _ = straight_run
    cfg2 = tiny_config("train.seed=1", "train.steps=2")
    train(cfg2, tmp_path / "seed1", progress=False)
    rows = _log_rows(tmp_path / "seed1")
    assert rows[0]["loss"] != _log_rows(straight_dir)[0]["loss"]


def test_run_directory_holds_config_log_checkpoints_doe_and_figures(straight_run):
    cfg, run_dir, result = straight_run
    assert result.step == 8 and np.isfinite(result.loss)
    assert to_dict(load_config(str(run_dir / "config.yaml"))) == to_dict(cfg)
    with open(run_dir / "train_log.csv", newline="") as handle:
        assert tuple(next(csv.reader(handle))) == COLUMNS
    rows = _log_rows(run_dir)
    lrs = [float(r["lr"]) for r in rows]
    assert lrs[0] == pytest.approx(cfg.train.lr_net) and all(b < a for a, b in zip(lrs, lrs[1:]))
    assert all(float(r["mse"]) > 0 for r in rows)
    steps = sorted(p.name for p in (run_dir / "checkpoints").iterdir())
    assert steps == ["last.pt", "step_000006.pt", "step_000008.pt"]  # keep_checkpoints = 2
    doe = load_doe(run_dir / "doe.npz")
    assert len(doe.table_height_m) == cfg.psf.pupil_samples // 2
    levels = np.load(run_dir / "doe.npz")["level"]
    assert levels.min() >= 0 and levels.max() < cfg.doe.levels
    for name in ("loss.png", "doe_profile.png", "psf_depths.png"):
        assert (run_dir / "figures" / name).stat().st_size > 1000
    assert not (run_dir / "metrics.csv").exists()


def test_load_run_gives_the_trained_network_and_fabricated_doe(straight_run):
    cfg, run_dir, _ = straight_run
    run = load_run(run_dir)
    assert run.step == 8 and run.cfg == cfg
    checkpoint = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    for key, value in run.net.state_dict().items():
        assert torch.equal(value, checkpoint["net"][key])
    r = torch.linspace(0, 0.99 * run.doe.aperture_radius_m, 50, dtype=torch.float64)
    trained_doe = build_run_doe(cfg)
    trained_doe.load_state_dict(checkpoint["doe"])
    torch.testing.assert_close(run.doe.height_m(r), trained_doe.height_m(r).double(), rtol=0, atol=1e-12)


def test_load_run_without_checkpoint_is_a_one_line_error(tmp_path):
    (tmp_path / "config.yaml").write_text(dump_config(tiny_config()))
    with pytest.raises(EdofprojError, match="no checkpoint") as info:
        load_run(tmp_path)
    assert "\n" not in str(info.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(EdofprojError, match="not a training run"):
        load_run(tmp_path / "empty")


def test_refuses_to_overwrite_and_to_resume_with_another_config(straight_run, tmp_path):
    cfg, run_dir, _ = straight_run
    with pytest.raises(EdofprojError, match="not empty"):
        train(cfg, run_dir, progress=False)
    with pytest.raises(EdofprojError, match="lr_net"):
        train(tiny_config("train.lr_net=0.01"), run_dir, resume=True, progress=False)
    with pytest.raises(EdofprojError):  # nothing to resume: no run's config.yaml
        train(cfg, tmp_path / "never-trained", resume=True, progress=False)
    stopped_early = tmp_path / "stopped-early"  # killed before its first checkpoint: only its config.yaml
    stopped_early.mkdir()
    (stopped_early / "config.yaml").write_text(dump_config(cfg))
    with pytest.warns(RecoveryWarning, match="before its first checkpoint: training it from step 0"):
        restarted = train(cfg, stopped_early, resume=True, progress=False)
    assert (restarted.start_step, restarted.step) == (0, 8)
    done = train(cfg, run_dir, resume=True, progress=False)  # nothing left to do
    assert (done.start_step, done.step) == (8, 8)


def test_non_finite_loss_stops_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    real_build_loss = losses.build_loss

    def build_poisoned_loss(loss_cfg):
        loss = real_build_loss(loss_cfg)
        calls = {"n": 0}
        real_terms = loss.terms

        def terms(pred, target):
            calls["n"] += 1
            out = real_terms(pred, target)
            if calls["n"] == 5:
                out["total"] = out["total"] * float("nan")
            return out

        loss.terms = terms
        return loss

    monkeypatch.setattr(trainer_module, "build_loss", build_poisoned_loss)
    with pytest.raises(EdofprojError, match="loss became nan at step 5; the last good checkpoint is step 4") as info:
        train(tiny_config(), tmp_path / "nan", progress=False)
    assert "\n" not in str(info.value)
    assert load_checkpoint(tmp_path / "nan" / "checkpoints" / "last.pt")["step"] == 4
    assert [r["step"] for r in _log_rows(tmp_path / "nan")] == ["1", "2", "3", "4"]


def test_lens_baseline_trains_only_the_network(tmp_path):
    cfg = tiny_config("doe.kind=lens", "train.steps=2")
    train(cfg, tmp_path / "lens", progress=False)
    assert not (tmp_path / "lens" / "doe.npz").exists()
    checkpoint = load_checkpoint(tmp_path / "lens" / "checkpoints" / "last.pt")
    assert [g["name"] for g in checkpoint["optimizer"]["param_groups"]] == ["net"]
    seed_everything(cfg.train.seed)
    build_run_doe(cfg)
    initial = build_network(cfg.net).state_dict()
    assert any(not torch.equal(initial[k], checkpoint["net"][k]) for k in initial)
    assert load_run(tmp_path / "lens").doe.name == "lens"


def test_frozen_network_trains_only_the_doe_and_fixed_everything_is_refused(tmp_path):
    cfg = tiny_config("train.train_net=false", "train.steps=2")
    train(cfg, tmp_path / "doe_only", progress=False)
    checkpoint = load_checkpoint(tmp_path / "doe_only" / "checkpoints" / "last.pt")
    assert [g["name"] for g in checkpoint["optimizer"]["param_groups"]] == ["doe"]
    seed_everything(cfg.train.seed)
    build_run_doe(cfg)
    initial = build_network(cfg.net).state_dict()
    assert all(torch.equal(initial[k], checkpoint["net"][k]) for k in initial)
    with pytest.raises(EdofprojError, match="nothing to train"):
        train(tiny_config("doe.kind=lens", "train.train_net=false"), tmp_path / "none", progress=False)


def test_two_dimensional_fixed_doe_trains_through_a_psf_table(tmp_path):
    cfg = tiny_config("doe.kind=cubic", "doe.cubic_waves=2", "train.steps=2")
    result = train(cfg, tmp_path / "cubic", progress=False)
    assert result.step == 2 and np.isfinite(result.loss)
    assert str(np.load(tmp_path / "cubic" / "doe.npz")["kind"]) == "map"


def test_cli_trains_and_refuses_an_existing_run_in_one_line(tmp_path, capsys):
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_config(tiny_config()))
    out = tmp_path / "cli_run"
    assert main(["train", "--config", str(config), "--out", str(out), "--steps", "2", "--quiet"]) == 0
    assert "steps 0 -> 2 of 2" in capsys.readouterr().out
    assert main(["train", "--config", str(config), "--out", str(out), "--steps", "2", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("edofproj: error:") and "--resume" in err and err.count("\n") == 1
    # resume from the run's own config.yaml, extending the run
    assert main(["train", "--out", str(out), "--resume", "--steps", "3", "--quiet"]) == 0
    assert "steps 2 -> 3 of 3" in capsys.readouterr().out
    assert load_config(str(out / "config.yaml")).name == "cli_run"


def test_onlineprodeb_baseline_trains_with_the_same_loop(tmp_path):
    cfg = tiny_config("doe.kind=lens", "net.architecture=onlineprodeb", "train.steps=1")
    result = train(cfg, tmp_path / "opd", progress=False)
    assert result.step == 1 and np.isfinite(result.loss)
    run = load_run(tmp_path / "opd")
    assert type(run.net).__name__ == "OnlineProDebNet"
    seed_everything(cfg.train.seed)
    build_run_doe(cfg)
    initial = build_network(cfg.net).state_dict()
    assert any(not torch.equal(initial[k], v) for k, v in run.net.state_dict().items())
