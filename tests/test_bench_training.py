"""``benchmarks/bench_training.py`` runs from a fresh clone: what a preset needs and the folder lacks
(the realtime preset's DOE of a demo run, the paper preset's DIV2K) is substituted, with a note."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

from edofproj.builtin_runs import builtin_run_dir
from edofproj.config import load_config
from edofproj.doe.factory import resolve_doe_file

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "bench_training.py"


def bench_module():
    spec = importlib.util.spec_from_file_location("bench_training", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_realtime_preset_is_timed_on_the_shipped_doe_where_no_demo_has_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a fresh clone: no runs/demo here
    bench = bench_module()
    extra, notes = bench.substitutions("realtime", [])
    assert extra == ["doe.path=builtin:cpu-doe-net"]
    assert notes == ["doe: the DOE of builtin:cpu-doe-net instead of the absent 'runs/demo/doe_net/doe.npz'"]
    cfg = load_config("realtime", extra)
    assert resolve_doe_file(cfg.doe.path) == builtin_run_dir("cpu-doe-net") / "doe.npz"


def test_a_demo_doe_present_is_used_and_presets_with_everything_are_left_alone(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    demo_doe = tmp_path / "runs" / "demo" / "doe_net" / "doe.npz"
    demo_doe.parent.mkdir(parents=True)
    shutil.copy(builtin_run_dir("cpu-doe-net") / "doe.npz", demo_doe)
    bench = bench_module()
    assert bench.substitutions("realtime", []) == ([], [])
    assert bench.substitutions("cpu", []) == ([], [])
    extra, notes = bench.substitutions("paper", [])
    assert extra == ["data.source=dead-leaves", "data.folder=null"] and notes[0].startswith("data: dead-leaves")


def test_precision_float32_turns_the_cpu_presets_bf16_autocast_off():
    """``--precision float32`` times float32 on any CPU; the preset's own ``auto`` is bf16 only where the
    CPU computes bfloat16 natively."""
    import torch

    from edofproj.training.end_to_end import native_bf16

    bench = bench_module()
    assert bench.precision_that_runs(load_config("cpu", bench.PRECISION_OVERRIDES["float32"])) == "float32"
    assert bench.precision_that_runs(load_config("cpu", bench.PRECISION_OVERRIDES["bf16"])) == "bf16"
    native = native_bf16(torch.device("cpu"))
    assert bench.precision_that_runs(load_config("cpu", bench.PRECISION_OVERRIDES["config"])) == (
        "bf16" if native else "float32"
    )
