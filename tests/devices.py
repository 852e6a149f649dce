"""Which devices the tests run on: the CPU always, a CUDA GPU when PyTorch sees one.

On a machine without CUDA the GPU cases are skipped with :data:`NO_CUDA` as the reason; on the
GPU machine ``benchmarks/gpu/run_gpu_checks.sh tests`` runs them (every test with ``cuda`` in its
name or parameters), after ``tests/test_device_placement.py`` has checked on the CPU that every
tensor is made on its inputs' device.
"""

import pytest
import torch

HAS_CUDA = torch.cuda.is_available()
NO_CUDA = "needs a CUDA GPU (PyTorch sees none here); benchmarks/gpu/run_gpu_checks.sh runs it on one"
cuda_only = pytest.mark.skipif(not HAS_CUDA, reason=NO_CUDA)
DEVICES = ["cpu", pytest.param("cuda", marks=cuda_only)]
