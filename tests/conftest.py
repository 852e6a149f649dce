import pytest
import torch

from devices import DEVICES

# Tests use small tensors: one thread is fastest for them and predictable on shared 2-core machines.
torch.set_num_threads(1)


@pytest.fixture
def geometry():
    from edofproj.optics.geometry import ProjectorGeometry

    return ProjectorGeometry(
        aperture_diameter_m=7e-3, focus_distance_m=0.5, throw_ratio=1.5, width_px=800, height_px=600
    )


@pytest.fixture(params=DEVICES)
def device(request):
    """Each test that takes ``device`` runs on the CPU and, when PyTorch sees one, on a CUDA GPU."""
    return torch.device(request.param)


@pytest.fixture
def float32_matmul():
    """float32 convolutions and matrix products in full float32 on CUDA (no TF32), so that CPU and
    CUDA results can be compared to float32 rounding; the previous settings are restored after."""
    saved = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved


@pytest.fixture
def tiny_config():
    """``tiny_config(*overrides, kind="training")``: one of the tiny configurations of
    :mod:`tiny_configs` (``training``, ``evaluation``, ``lens-finetune``) plus overrides."""
    from edofproj.config import Config, apply_overrides
    from tiny_configs import TINY

    def make(*overrides: str, kind: str = "training"):
        return apply_overrides(Config(), TINY[kind] + list(overrides))

    return make
