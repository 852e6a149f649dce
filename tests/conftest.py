
import pytest
import torch

# Tests use small tensors: one thread is fastest for them and predictable on shared 2-core machines.
torch.set_num_threads(1)


@pytest.fixture
def geometry():
    from edofproj.optics.geometry import ProjectorGeometry

    return ProjectorGeometry(aperture_diameter_m=7e-3, focus_distance_m=0.5, throw_ratio=1.5, width_px=800, height_px=600)
