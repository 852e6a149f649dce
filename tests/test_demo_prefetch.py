"""The demo simulates the cubic plate's PSFs on the core a training worker leaves free, and the evaluation takes
them: the hook fires once when a worker runs out of jobs while another trains, the evaluation adopts only a
design made with its own configuration, and the PSFs so simulated are the ones the evaluation would compute."""

from __future__ import annotations

import numpy as np
import torch

from edofproj.application import schedule
from edofproj.application.demo import DesignPrefetch, design_evaluation_depths_m
from edofproj.application.schedule import ParallelTrainer, TrainingJob
from edofproj.methods.builder import MethodBuilder
from edofproj.methods.designs import OpticalDesign
from edofproj.progress import StageProgress
from edofproj.runs import write_run_config


class FakeProcess:
    """A training process that ends (exit 0) after ``polls`` polls."""

    def __init__(self, polls: int) -> None:
        self.left = polls

    def poll(self):
        self.left -= 1
        return 0 if self.left <= 0 else None


def test_the_idle_worker_hook_fires_once_when_a_worker_is_left_without_a_job(tmp_path, monkeypatch):
    jobs = [
        TrainingJob("doe+net", tmp_path / "doe_net", [], 10),
        TrainingJob("lens+net", tmp_path / "lens_net", [], 10),
        TrainingJob("axicon+net", tmp_path / "axicon_net", [], 10),
    ]
    lengths = {"doe+net": 8, "lens+net": 2, "axicon+net": 2}

    def start(self, job):
        job.process, job.status = FakeProcess(lengths[job.method]), "running"

    monkeypatch.setattr(ParallelTrainer, "start", start)
    monkeypatch.setattr(schedule, "POLL_S", 0.0)
    seen = []

    def idle():
        seen.append({j.method: j.status for j in jobs})

    trainer = ParallelTrainer(jobs, "cpu", tmp_path / "logs", 2, 1e12, StageProgress("t", enabled=False))
    trainer.on_idle_worker = idle
    trainer.run()
    # lens+net ends, axicon+net takes its worker; when axicon+net ends nothing is left: the hook, once
    assert seen == [{"doe+net": "running", "lens+net": "done", "axicon+net": "done"}]
    assert all(j.status == "done" for j in jobs)


def tiny_run(tmp_path, tiny_config, *overrides):
    cfg = tiny_config("psf.pupil_samples=512", *overrides, kind="evaluation")  # the cubic plate needs 512
    run = tmp_path / "demo" / "doe_net"
    run.mkdir(parents=True)
    write_run_config(run, cfg)
    return run, cfg


def test_an_evaluation_adopts_only_a_design_of_its_own_configuration(tmp_path, tiny_config):
    run, cfg = tiny_run(tmp_path, tiny_config)
    same = MethodBuilder(None, cfg, tmp_path, explicit=False).classic_design("cubic")
    builder = MethodBuilder(None, cfg, tmp_path, explicit=False)
    assert builder.adopt([same]) == ["cubic"] and builder.classic_design("cubic") is same
    other_cfg = tiny_config("psf.pupil_samples=512", "doe.cubic_waves=3", kind="evaluation")
    other = MethodBuilder(None, other_cfg, tmp_path, explicit=False).classic_design("cubic")
    fresh = MethodBuilder(None, cfg, tmp_path, explicit=False)
    assert fresh.adopt([other]) == [] and fresh.classic_design("cubic") is not other


def test_the_prefetched_psfs_are_those_the_evaluation_simulates_itself(tmp_path, tiny_config):
    run, cfg = tiny_run(tmp_path, tiny_config)
    methods = ["lens", "cubic+wiener"]
    depths_m = design_evaluation_depths_m(cfg, methods, "cubic")
    assert len(depths_m) > 5  # the sweep, tuning, tilted-screen and figure depths
    threads = torch.get_num_threads()
    prefetch = DesignPrefetch(run, methods)
    prefetch.start()
    prefetch._thread.join()  # let it simulate every depth
    (design,) = prefetch.finish()
    assert torch.get_num_threads() == threads  # restored after the thread's one
    assert prefetch.simulated == len(depths_m) and len(design._cache) == len(depths_m)
    # the evaluation's own simulation: all depths at once, on this thread's threads
    own = OpticalDesign("cubic", "cubic", design.doe, cfg)
    some = depths_m[[0, len(depths_m) // 2, -1]]
    np.testing.assert_array_equal(own.psf(some).numpy(), design.psf(some).numpy())


def test_a_prefetch_stopped_by_the_end_of_training_leaves_the_rest_to_the_evaluation(tmp_path, tiny_config):
    run, _ = tiny_run(tmp_path, tiny_config)
    prefetch = DesignPrefetch(run, ["cubic+wiener"])
    prefetch._stop.set()  # training ended before the thread's first depth
    prefetch.start()
    (design,) = prefetch.finish()
    assert prefetch.simulated == 0 and design._cache == {}
    assert DesignPrefetch(run, ["lens", "doe+net"]).finish() == []  # no cubic method: nothing started
    missing = DesignPrefetch(tmp_path / "absent", ["cubic+wiener"])
    missing.start()  # no config.yaml yet: nothing to do
    assert missing.finish() == []
