"""The GPU scripts hold together before a GPU runs them: a loan must not end on a typo.

``benchmarks/gpu/run_gpu_checks.sh`` is valid bash and names steps that exist;
``benchmarks/gpu/paper_scale.py`` imports (every name it takes from edofproj exists) and parses its
options; every job of ``benchmarks/gpu/realtime_search.py`` is a configuration the trainer accepts, and its
summary computes the scores' mean and worst depth. What they do on a GPU is checked there; tests/test_device_placement.py checks the device
placement of the code they run.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

GPU = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu"


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_run_gpu_checks_is_valid_bash_with_a_function_for_each_step():
    script = GPU / "run_gpu_checks.sh"
    subprocess.run(["bash", "-n", str(script)], check=True)
    text = script.read_text()
    usage = re.search(r"run_gpu_checks\.sh \[([a-z|]+)\]", text)
    assert usage is not None
    for step in usage.group(1).split("|"):
        assert step == "all" or re.search(rf"^{step}\(\) {{", text, re.M), step


def test_paper_scale_imports_and_parses_its_options(monkeypatch, capsys):
    spec = importlib.util.spec_from_file_location("paper_scale", GPU / "paper_scale.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "argv", ["paper_scale.py", "--help"])
    with pytest.raises(SystemExit) as exit_code:
        module.main()
    assert exit_code.value.code == 0 and "--precisions" in capsys.readouterr().out


def load_realtime_search():
    spec = importlib.util.spec_from_file_location("realtime_search", GPU / "realtime_search.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_realtime_search_trains_valid_configurations(tmp_path):
    """Every job of every grid is a configuration the trainer accepts, with the steps and batch it names."""
    from edofproj.config import load_config

    search = load_realtime_search()
    for grid, jobs in search.GRIDS.items():
        for name, overrides, _ in jobs:
            command = search.train_command(tmp_path / name, overrides, 700, "cpu")
            sets = [command[i + 1] for i, arg in enumerate(command) if arg == "--set"]
            cfg = load_config(command[command.index("--config") + 1], sets)
            assert cfg.train.steps == 700 and cfg.train.checkpoint_every == 175, (grid, name)
            assert cfg.train.batch_size == (4 if "batch4" in name else 16), (grid, name)
            assert cfg.net.block_px == (2 if name.startswith("b2_") else 4), (grid, name)
            assert (cfg.data.colour_augment == 0.3) == ("colour" in name), (grid, name)


def test_realtime_search_summary_is_the_mean_over_depths_of_the_mean_over_images(tmp_path, capsys):
    """Two images at 300 and 800 mm (and 250 mm, outside the scored range): mean and worst by hand."""
    search = load_realtime_search()
    rows = ["job,set,method,depth_mm,image,ssim,de2000"]
    values = {(300, "a"): 0.90, (300, "b"): 0.80, (800, "a"): 0.70, (800, "b"): 0.60, (250, "a"): 0.0}
    for (depth_mm, image), ssim in values.items():
        rows.append(f"net,test,doe+net,{depth_mm},{image},{ssim},2.0")
        rows.append(f"net,test,doe+ensemble,{depth_mm},{image},1.0,9.0")
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    search.summarize(tmp_path / "metrics.csv")
    line = [row for row in capsys.readouterr().out.splitlines() if row.startswith("| net |")][0]
    # depth means 0.85 (300 mm) and 0.65 (800 mm): mean 0.75, worst 0.65 at 800 mm
    assert "0.7500 / 0.6500 (800)" in line
    assert f"{0.75 - search.REFERENCE['test'][0]:+.4f} / {0.65 - search.REFERENCE['test'][1]:+.4f}" in line
    assert "| 2.00 |" in line
