"""The arithmetic a test that trains a network runs in, and the legs that check every one.

``train.mixed_precision: auto`` trains the network in bfloat16 autocast on a CPU that computes it
natively (AVX-512-BF16 or AMX) and in float32 elsewhere, and float32 itself is computed by AVX-512 or
AVX2 kernels by the CPU. A test whose outcome depends on what a network learns (it is marked
``arithmetic``) must pass in each of them, not only on the machine that runs the suite:
``tests/test_arithmetic_legs.py`` reruns the marked tests in subprocesses, once per leg of
:data:`LEGS` (:envvar:`EDOFPROJ_TEST_MIXED_PRECISION` sets the precision, the ``ATEN``/oneDNN/MKL
variables limit float32 to AVX2 where the CPU has more).
"""

from __future__ import annotations

import os

PRECISION_VARIABLE = "EDOFPROJ_TEST_MIXED_PRECISION"

# float32 as a CPU with AVX2 only computes it (PyTorch's own kernels, oneDNN and MKL)
AVX2_FLOAT32 = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2"}

LEGS: dict[str, dict[str, str]] = {
    "bf16": {PRECISION_VARIABLE: "bf16"},  # bfloat16 autocast (emulated where the CPU lacks it)
    "float32": {PRECISION_VARIABLE: "none"},  # float32 in the CPU's widest kernels
    "float32-avx2": {PRECISION_VARIABLE: "none", **AVX2_FLOAT32},
}


def mixed_precision_under_test() -> str:
    """``train.mixed_precision`` for the tests marked ``arithmetic``: :envvar:`EDOFPROJ_TEST_MIXED_PRECISION`,
    else ``auto`` (what the presets ship: bf16 only where native)."""
    value = os.environ.get(PRECISION_VARIABLE, "auto")
    if value not in ("auto", "none", "bf16"):
        raise ValueError(f"{PRECISION_VARIABLE}={value!r} is not one of auto, none, bf16")
    return value
