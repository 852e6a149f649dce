"""A run in two phases (``train.refit_steps``): the DOE and a network jointly, then a fresh network for
the fabricated DOE. The second phase must be exactly a separate run of the refit recipe on that DOE,
leave the DOE as the first phase fabricated it, and resume bit for bit from a checkpoint in either
phase."""

from __future__ import annotations

import csv
import shutil

import numpy as np
import pytest
import torch

from edofproj.compensation.registry import build_network
from edofproj.config import Config, apply_overrides, to_dict
from edofproj.errors import ConfigError, EdofprojError
from edofproj.runs import load_run
from edofproj.runs.checkpoint import load_checkpoint
from edofproj.training.phases import JOINT, REFIT, REFIT_KEY_SOURCES, run_key, total_steps, training_phases
from edofproj.training.trainer import train
from edofproj.training.validation import VALIDATION_LOG, read_validation_log
from tiny_configs import TINY_TRAINING

JOINT_STEPS, REFIT_STEPS = 4, 3
TWO_PHASES = TINY_TRAINING + [
    "net.linear_base=ensemble",
    "net.linear_radius=11",
    "train.batch_size=2",
    f"train.steps={JOINT_STEPS}",
    f"train.refit_steps={REFIT_STEPS}",
    "train.refit_lr_net=0.004",
    "train.refit_warmup_steps=2",
    "train.refit_colour_augment=0.0",
    "data.colour_augment=0.5",
    "train.checkpoint_every=2",
    "train.keep_checkpoints=0",
    "train.psf_table_depths=16",
    "train.linear_every=2",
    "train.validate_every=2",
    "train.validation_images=2",
]


def two_phase_config(*extra: str) -> Config:
    return apply_overrides(Config(), TWO_PHASES + list(extra))


def _log(run_dir):
    with open(run_dir / "train_log.csv", newline="") as handle:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(handle)]


# ----------------------------------------------------------------------------- the phases of a configuration


def test_a_learned_doe_trains_jointly_then_a_fresh_network_is_refit_for_it():
    cfg = two_phase_config()
    joint, refit = training_phases(cfg)
    assert (joint.name, joint.offset, joint.cfg.train.steps, joint.cfg.train.train_doe) == (JOINT, 0, 4, True)
    assert joint.cfg.data.colour_augment == 0.5 and joint.cfg.train.lr_net == cfg.train.lr_net
    assert (refit.name, refit.offset, refit.end, refit.doe_from_run) == (REFIT, 4, 7, True)
    assert refit.cfg.train.train_doe is False and refit.cfg.train.lr_net == 0.004
    assert refit.cfg.train.warmup_steps == 2 and refit.cfg.data.colour_augment == 0.0
    assert total_steps(cfg) == 7


def test_a_fixed_doe_has_only_the_refit_phase_and_no_refit_keeps_one_phase():
    (only,) = training_phases(two_phase_config("doe.kind=lens"))
    assert (only.name, only.offset, only.cfg.train.steps, only.doe_from_run) == (REFIT, 0, 3, False)
    assert only.cfg.train.lr_net == 0.004
    (single,) = training_phases(two_phase_config("train.refit_steps=0"))
    assert (single.name, single.cfg.train.steps, single.cfg.train.lr_net) == (JOINT, 4, 1e-3)


REFIT_NET = ["refit_net.architecture=multirate", "refit_net.block_px=2", "refit_net.widths=[4,4]"]


def test_the_refit_phase_trains_the_refit_net_section_in_its_own_batches():
    cfg = two_phase_config(*REFIT_NET, "train.refit_batch_size=3")
    joint, refit = training_phases(cfg)
    assert joint.cfg.net == cfg.net and joint.cfg.train.batch_size == 2 and joint.cfg.refit_net is None
    assert refit.cfg.net == cfg.refit_net and refit.cfg.net.architecture == "multirate"
    assert refit.cfg.train.batch_size == 3 and refit.cfg.refit_net is None
    # refit_net starts as a copy of net: the options the two architectures share are net's
    assert (refit.cfg.net.linear_radius, refit.cfg.net.widths) == (cfg.net.linear_radius, [4, 4])
    # the network a checkpoint holds: net through the joint phase, refit_net after it
    assert [cfg.network_at(s).architecture for s in (1, JOINT_STEPS, JOINT_STEPS + 1)] == ["unet", "unet", "multirate"]
    assert cfg.final_network() == cfg.refit_net
    # without a refit phase, or without the section, the run has one network
    assert two_phase_config(*REFIT_NET, "train.refit_steps=0").final_network().architecture == "unet"
    assert two_phase_config().final_network() == two_phase_config().net
    # a fixed DOE has only the refit phase: its network is refit_net from the first step
    assert two_phase_config(*REFIT_NET, "doe.kind=lens").network_at(1).architecture == "multirate"


def test_run_key_names_the_run_key_that_sets_each_refit_phase_key():
    """Each key of the refit phase that run_key names by another key changes when (and only when) that run key
    is set: the names the demo prints stay true to refit_config."""
    (refit,) = training_phases(two_phase_config("doe.kind=lens"))
    values = {"train.refit_steps": 5, "train.refit_lr_net": 0.0123, "train.refit_warmup_steps": 1,
              "train.refit_colour_augment": 0.25, "train.refit_batch_size": 3, "refit_net.widths": [6, 6]}  # fmt: skip
    phase_keys = {**REFIT_KEY_SOURCES, "train.batch_size": "train.refit_batch_size", "net.widths": "refit_net.widths"}
    for phase_key, source in phase_keys.items():
        extra = [*REFIT_NET] if source.startswith("refit_net.") else []
        changed = two_phase_config("doe.kind=lens", *extra, f"{source}={values[source]}")
        (phase,) = training_phases(changed)
        section, name = phase_key.split(".")
        assert getattr(getattr(phase.cfg, section), name) == values[source], phase_key
        assert run_key(phase, phase_key, changed) == source, phase_key
        assert run_key(refit, phase_key, two_phase_config("doe.kind=lens")) == (
            phase_key if phase_key in ("train.batch_size", "net.widths") else source
        ), phase_key  # without refit_batch_size or a refit_net section the phase reads the run's own key
    # a joint phase reads the run's keys as they are
    joint, _ = training_phases(two_phase_config())
    assert run_key(joint, "train.steps", two_phase_config()) == "train.steps"


def test_refit_net_survives_the_round_trip_and_refuses_unknown_keys():
    cfg = two_phase_config(*REFIT_NET)
    assert apply_overrides(cfg, []) == cfg and to_dict(cfg)["refit_net"]["architecture"] == "multirate"
    assert to_dict(two_phase_config())["refit_net"] is None
    with pytest.raises(ConfigError, match="refit_net.block_pixels"):
        two_phase_config(*REFIT_NET, "refit_net.block_pixels=2")
    with pytest.raises(ConfigError, match="refit_batch_size"):
        two_phase_config("train.refit_batch_size=-1")


# ----------------------------------------------------------------------------- a run in two phases

slow = pytest.mark.slow


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("phases") / "straight"
    result = train(two_phase_config(), run_dir, progress=False)
    return run_dir, result


@slow
def test_the_run_counts_on_across_its_phases_and_keeps_the_fabricated_doe(straight):
    run_dir, result = straight
    assert (result.start_step, result.step) == (0, 7)
    rows = _log(run_dir)
    assert [int(r["step"]) for r in rows] == list(range(1, 8))
    with open(run_dir / "train_log.csv", newline="") as handle:  # the training seconds go on across the phases
        seconds = [float(row["seconds"]) for row in csv.DictReader(handle)]
    assert seconds[JOINT_STEPS] > seconds[JOINT_STEPS - 1] and seconds == sorted(seconds)
    # the refit phase starts its own warm-up: lr_0 / W at its first step
    assert float(rows[JOINT_STEPS]["lr"]) == pytest.approx(0.004 / 2)
    assert [r["step"] for r in read_validation_log(run_dir / VALIDATION_LOG)] == [2.0, 4.0, 6.0, 7.0]
    end_of_joint = load_checkpoint(run_dir / "checkpoints" / "step_000004.pt")
    final = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert (end_of_joint["phase"], final["phase"], final["phase_step"]) == (JOINT, REFIT, REFIT_STEPS)
    assert end_of_joint["config"] == final["config"] == to_dict(two_phase_config())  # the run's, not the phase's
    assert any(not torch.equal(v, final["net"][k]) for k, v in end_of_joint["net"].items())


@slow
def test_the_refit_phase_is_a_separate_run_of_its_recipe_on_the_fabricated_doe(straight, tmp_path):
    run_dir, _ = straight
    doe_file = tmp_path / "doe.npz"
    shutil.copyfile(run_dir / "doe.npz", doe_file)
    separate = two_phase_config(
        "doe.kind=file",
        f"doe.path={doe_file}",
        "train.refit_steps=0",
        f"train.steps={REFIT_STEPS}",
        "train.lr_net=0.004",
        "train.warmup_steps=2",
        "data.colour_augment=0.0",
    )
    train(separate, tmp_path / "separate", progress=False)
    a = load_checkpoint(run_dir / "checkpoints" / "last.pt")["net"]
    b = load_checkpoint(tmp_path / "separate" / "checkpoints" / "last.pt")["net"]
    for key, value in a.items():
        assert torch.equal(value, b[key]), key
    assert [r["loss"] for r in _log(run_dir)[JOINT_STEPS:]] == [r["loss"] for r in _log(tmp_path / "separate")]


@slow
@pytest.mark.parametrize("stop", [3, JOINT_STEPS, JOINT_STEPS + 1])
def test_a_run_stopped_in_either_phase_resumes_bit_for_bit(straight, tmp_path, stop):
    straight_dir, _ = straight
    cfg = two_phase_config()
    run_dir = tmp_path / "chunked"
    first = train(cfg, run_dir, stop_after=stop, progress=False)
    assert first.step == stop
    second = train(cfg, run_dir, resume=True, progress=False)
    assert (second.start_step, second.step) == (stop, 7)
    a = load_checkpoint(straight_dir / "checkpoints" / "last.pt")
    b = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    for key, value in a["net"].items():
        assert torch.equal(value, b["net"][key]), key
    assert _log(straight_dir) == _log(run_dir)
    assert read_validation_log(straight_dir / VALIDATION_LOG) == read_validation_log(run_dir / VALIDATION_LOG)
    assert np.array_equal(np.load(straight_dir / "doe.npz")["height_m"], np.load(run_dir / "doe.npz")["height_m"])


@slow
@pytest.mark.parametrize("stop", [JOINT_STEPS - 1, JOINT_STEPS + 1])
def test_a_run_with_a_refit_net_loads_the_network_of_its_phase_and_resumes_bit_for_bit(tmp_path, stop):
    cfg = two_phase_config(*REFIT_NET, "train.refit_batch_size=3")
    straight_dir, chunked = tmp_path / "straight", tmp_path / "chunked"
    train(cfg, straight_dir, progress=False)
    train(cfg, chunked, stop_after=stop, progress=False)
    halfway = load_run(chunked)
    assert halfway.step == stop and type(halfway.net).__name__ == build_network(cfg.network_at(stop)).__class__.__name__
    assert halfway.cfg.net == cfg.network_at(stop)
    train(cfg, chunked, resume=True, progress=False)
    finished = load_run(chunked)
    assert finished.cfg.net == cfg.refit_net and finished.cfg.refit_net == cfg.refit_net
    a = load_checkpoint(straight_dir / "checkpoints" / "last.pt")["net"]
    b = load_checkpoint(chunked / "checkpoints" / "last.pt")["net"]
    assert a.keys() == build_network(cfg.refit_net).state_dict().keys()
    for key, value in a.items():
        assert torch.equal(value, b[key]), key
    assert _log(straight_dir) == _log(chunked)


@slow
def test_resuming_the_refit_phase_with_another_joint_length_is_refused(tmp_path):
    run_dir = tmp_path / "run"
    train(two_phase_config(), run_dir, stop_after=JOINT_STEPS + 2, progress=False)
    with pytest.raises(EdofprojError, match="keep train.steps"):
        train(two_phase_config(f"train.steps={JOINT_STEPS + 2}"), run_dir, resume=True, progress=False)
