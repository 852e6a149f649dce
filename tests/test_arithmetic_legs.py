"""The tests marked ``arithmetic`` pass in every arithmetic ``train.mixed_precision: auto`` can pick:
bfloat16 autocast, float32 in the CPU's widest kernels and float32 limited to AVX2 (:mod:`arithmetic`),
each leg a pytest subprocess, whatever this machine's own CPU would pick."""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from arithmetic import AVX2_FLOAT32, LEGS, PRECISION_VARIABLE

pytestmark = pytest.mark.slow  # reruns trainings in subprocesses

TESTS = Path(__file__).resolve().parent


def marked_files() -> list[str]:
    """The test files that mark a test ``arithmetic`` (each leg collects only these, so that another
    file's import does not stand between a leg and its tests)."""
    return sorted(str(p) for p in TESTS.glob("test_*.py") if "@pytest.mark.arithmetic" in p.read_text())


def run_marked(env=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-m", "arithmetic", "-p", "no:cacheprovider", *marked_files()],
        capture_output=True,
        text=True,
        cwd=TESTS.parent,
        env=env,
    )


def test_the_arithmetic_tests_are_found():
    names = [Path(f).name for f in marked_files()]
    assert {"test_live_end_to_end.py", "test_finetune.py", "test_procams_finetune.py"} <= set(names), names


#: the legs this machine can run: AVX2 limits apply to x86-64 CPUs only
LEGS_HERE = sorted(leg for leg in LEGS if leg != "float32-avx2" or platform.machine() in ("x86_64", "AMD64"))


@pytest.mark.parametrize("leg", LEGS_HERE)
def test_arithmetic_tests_pass_in_each_leg(leg):
    env = {k: v for k, v in os.environ.items() if k != PRECISION_VARIABLE and k not in AVX2_FLOAT32}
    env.update(LEGS[leg])
    result = run_marked(env)
    tail = "\n".join(result.stdout.splitlines()[-15:])
    assert result.returncode == 0, f"leg {leg} ({LEGS[leg]}):\n{tail}"
    assert " passed" in tail and "failed" not in tail and "error" not in tail, tail
