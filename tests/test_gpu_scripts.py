"""The GPU scripts hold together before a GPU runs them: a loan must not end on a typo.

``benchmarks/gpu/run_gpu_checks.sh`` is valid bash and names steps that exist;
``benchmarks/gpu/paper_scale.py`` imports (every name it takes from edofproj exists) and parses its
options. What they do on a GPU is checked there; tests/test_device_placement.py checks the device
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
