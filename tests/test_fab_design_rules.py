"""Design for manufacture: the minimum-feature parametrization cannot make rings narrower than the CD."""

import math

import numpy as np
import pytest
import torch

from edofproj.config import Config, apply_overrides
from edofproj.doe import build_doe, save_doe
from edofproj.doe.design_rules import MinimumFeatureRadialDOE, apply_design_rules
from edofproj.doe.mlp import FreeRadialDOE, RadialMLPDOE
from edofproj.errors import EdofprojError, SamplingError
from edofproj.fabrication.export import export_doe
from edofproj.fabrication.profile import RadialProfile
from edofproj.fabrication.report import CriticalDimensionError

R = 3.5e-3
PUPIL_SAMPLES = 256  # rings of 27.3 um
RING_M = R / (PUPIL_SAMPLES // 2)


def fine_structured_doe(seed=0):
    """A free radial profile with random heights on every ring: zones as narrow as one ring."""
    torch.manual_seed(seed)
    doe = FreeRadialDOE(R, rings=PUPIL_SAMPLES // 2)
    with torch.no_grad():
        doe.heights.uniform_(0.0, 1.0)
    return doe


def cfg_with_min_feature(um):
    return apply_overrides(Config(), [f"psf.pupil_samples={PUPIL_SAMPLES}", f"doe.min_feature_um={um}"])


def test_without_the_rule_fine_structure_fails_strict(tmp_path):
    save_doe(fine_structured_doe(), tmp_path / "fine.npz", samples=PUPIL_SAMPLES)
    assert RadialProfile.from_file(tmp_path / "fine.npz").narrowest_zone_m() == pytest.approx(RING_M)
    with pytest.raises(CriticalDimensionError, match="below the critical dimension 40 um"):
        export_doe(tmp_path / "fine.npz", tmp_path / "out", critical_dimension_um=40.0, strict=True)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("samples_factor", [1, 4])
def test_with_the_rule_every_feature_meets_the_cd(tmp_path, samples_factor):
    doe = apply_design_rules(fine_structured_doe(), cfg_with_min_feature(40.0))
    assert isinstance(doe, MinimumFeatureRadialDOE)
    assert doe.block_m == pytest.approx(2 * RING_M)  # 40 um rounded up to whole 27.3 um rings
    path = tmp_path / "rule.npz"
    save_doe(doe, path, samples=PUPIL_SAMPLES * samples_factor)  # finer files keep the block edges
    assert RadialProfile.from_file(path).narrowest_zone_m() >= 40e-6
    report = export_doe(path, tmp_path / "out", critical_dimension_um=40.0, strict=True)
    assert report["passes_critical_dimension"]
    assert min(m["narrowest_feature_um"] for m in report["masks"]) >= 40.0


def test_random_mlp_blocks_are_constant_and_at_least_min_feature():
    torch.manual_seed(3)
    inner = RadialMLPDOE(R, frequencies=9)
    torch.nn.init.normal_(inner.mlp[-1].weight, std=1.0)  # 352 level steps without the rule
    doe = MinimumFeatureRadialDOE(inner, 17e-6)  # no grid: blocks exactly 17 um, last one wider
    r = torch.linspace(0, R, 200001, dtype=torch.float64)
    with torch.no_grad():
        h = doe.height_m(r)
    change = torch.nonzero(torch.diff(h)).squeeze(-1)
    step_radii = r[change + 1].numpy()
    # height changes only at block edges, so every zone spans whole blocks
    assert len(step_radii) > 50
    np.testing.assert_allclose(step_radii / 17e-6, np.round(step_radii / 17e-6), atol=2 * (R / 200000) / 17e-6)
    zone_widths = np.diff(np.concatenate([[0.0], step_radii, [R]]))
    assert zone_widths.min() >= 17e-6 * (1 - 1e-3)
    assert doe.blocks == math.floor(R / 17e-6)


def test_gradient_reaches_the_inner_parameters():
    inner = fine_structured_doe()
    doe = MinimumFeatureRadialDOE(inner, 40e-6, grid_m=RING_M)
    r = torch.as_tensor((np.arange(PUPIL_SAMPLES // 2) + 0.5) * RING_M)
    doe.height_m(r).sum().backward()
    grad = inner.heights.grad
    assert grad is not None and torch.count_nonzero(grad) > 0
    # one ring per block is evaluated (the one at the block centre); 2 rings per block
    evaluated = torch.nonzero(grad).squeeze(-1)
    np.testing.assert_array_equal(torch.div(evaluated, 2, rounding_mode="floor").numpy(), np.arange(doe.blocks))


def test_apply_design_rules_off_and_errors():
    doe = fine_structured_doe()
    assert apply_design_rules(doe, cfg_with_min_feature(0.0)) is doe
    wrapped = apply_design_rules(doe, cfg_with_min_feature(5.0))
    assert wrapped.block_m == pytest.approx(RING_M)  # below one ring: one ring per block
    assert apply_design_rules(wrapped, cfg_with_min_feature(5.0)) is wrapped
    with pytest.raises(EdofprojError, match="radial DOEs only"):
        apply_design_rules(build_doe(Config(), "cubic"), cfg_with_min_feature(5.0))
    with pytest.raises(EdofprojError, match="wider than the aperture"):
        MinimumFeatureRadialDOE(doe, 2 * R)
    with pytest.raises(SamplingError, match="pupil_samples >= "):
        MinimumFeatureRadialDOE(doe, 10e-6).check_sampling(RING_M)
