"""Data-parallel training: ``torchrun --nproc_per_node=2 edofproj train`` (gloo, 2 CPU processes)
equals a single-process run with the same global batch."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from devices import DEVICES
from edofproj.config import Config, apply_overrides, dump_config
from edofproj.runs.checkpoint import load_checkpoint
from edofproj.training.trainer import train
from tiny_configs import TINY_TRAINING

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess


TINY = TINY_TRAINING + ["train.batch_size=4", "train.steps=3", "train.checkpoint_every=3", "train.noise_sigma=0.01"]


def tiny_config(*extra: str) -> Config:
    return apply_overrides(Config(), TINY + list(extra))


def assert_same_parameters(run: dict, reference: dict, cfg: Config) -> None:
    """The network and DOE parameters of two checkpoints agree to 1e-6, but for the DOE MLP's output
    bias: it sets a constant height offset, a global phase that leaves the PSFs unchanged, so its
    exact gradient is ~0 and Adam turns rounding noise in it into steps of up to lr each (its
    update is bounded by about lr per step): that one may differ by up to ``steps * lr_optics``."""
    for key, value in reference["net"].items():
        torch.testing.assert_close(run["net"][key], value, rtol=0, atol=1e-6)
    output_bias = f"mlp.{2 * cfg.doe.mlp_layers}.bias"  # Linear, ReLU, ..., Linear
    assert output_bias in reference["doe"]
    for key, value in reference["doe"].items():
        tolerance = cfg.train.steps * cfg.train.lr_optics if key == output_bias else 1e-6
        torch.testing.assert_close(run["doe"][key], value, rtol=0, atol=tolerance)


def torchrun(cfg: Config, tmp_path, processes: int, out: str) -> subprocess.CompletedProcess:
    """``torchrun --standalone --nproc_per_node=processes edofproj train`` of ``cfg`` into ``tmp_path/out``."""
    config_file = tmp_path / "tiny.yaml"
    config_file.write_text(dump_config(cfg))
    env = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
    env["OMP_NUM_THREADS"] = "1"
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc_per_node={processes}",
        "-m",
        "edofproj.cli",
        "train",
        "--config",
        str(config_file),
        "--out",
        str(tmp_path / out),
        "--quiet",
    ]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)


def test_two_process_run_matches_the_single_process_run(tmp_path):
    cfg = tiny_config()
    done = torchrun(cfg, tmp_path, 2, "ddp")
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.count("steps 0 -> 3 of 3") == 1  # only rank 0 reports (and writes)

    train(cfg, tmp_path / "single", progress=False)
    ddp = load_checkpoint(tmp_path / "ddp" / "checkpoints" / "last.pt")
    single = load_checkpoint(tmp_path / "single" / "checkpoints" / "last.pt")
    assert ddp["world_size"] == 2 and single["world_size"] == 1
    assert ddp["replica_max_difference"] == 0.0  # both ranks hold identical parameters
    assert_same_parameters(ddp, single, cfg)
    with open(tmp_path / "ddp" / "train_log.csv") as a, open(tmp_path / "single" / "train_log.csv") as b:
        losses_ddp = [float(line.split(",")[1]) for line in a.readlines()[1:]]
        losses_single = [float(line.split(",")[1]) for line in b.readlines()[1:]]
    torch.testing.assert_close(torch.tensor(losses_ddp), torch.tensor(losses_single), rtol=1e-5, atol=0)


@pytest.mark.parametrize("device", DEVICES)
def test_torchrun_with_one_process_joins_the_group_and_equals_the_plain_run(tmp_path, device):
    """``torchrun --nproc_per_node=1``: the process joins a group of one (gloo on the CPU, NCCL on a
    GPU), trains through DistributedDataParallel, and ends where a plain run ends."""
    cfg = tiny_config(f"train.device={device}")
    done = torchrun(cfg, tmp_path, 1, "group")
    assert done.returncode == 0, done.stderr[-2000:]

    train(cfg, tmp_path / "plain", progress=False)
    group = load_checkpoint(tmp_path / "group" / "checkpoints" / "last.pt")
    plain = load_checkpoint(tmp_path / "plain" / "checkpoints" / "last.pt")
    assert group["process_group"] == ("nccl" if device == "cuda" else "gloo")
    assert plain["process_group"] == "none"
    assert_same_parameters(group, plain, cfg)


def test_two_processes_train_both_phases_as_one_process_does(tmp_path):
    """A run of two phases under torchrun: every rank reads the DOE file rank 0 wrote at the phase boundary
    (after a barrier), and the second phase's network ends where a single process's does."""
    # Adam moves a parameter whose gradient is about 0 by up to the learning rate either way, so where the
    # two reductions round such a gradient apart the runs part by up to 2 lr a step: with the refit's rate
    # at 1e-5 the bound below checks where the phase starts (the DOE file read, the network built on it),
    # which a stale DOE would move by far more
    cfg = tiny_config(
        "net.linear_base=ensemble",
        "net.linear_radius=11",
        "train.refit_steps=3",
        "train.refit_warmup_steps=1",
        "train.refit_lr_net=1e-5",
    )
    done = torchrun(cfg, tmp_path, 2, "ddp")
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.count("steps 0 -> 6 of 6") == 1

    train(cfg, tmp_path / "single", progress=False)
    ddp = load_checkpoint(tmp_path / "ddp" / "checkpoints" / "last.pt")
    single = load_checkpoint(tmp_path / "single" / "checkpoints" / "last.pt")
    assert ddp["phase"] == single["phase"] == "refit" and ddp["replica_max_difference"] == 0.0
    for key, value in single["net"].items():
        torch.testing.assert_close(ddp["net"][key], value, rtol=0, atol=3e-5)
