"""Quantized radial profiles and their binary masks: etch convention, merging, exact reconstruction."""

import numpy as np
import pytest

from edofproj.config import Config, apply_overrides
from edofproj.doe import build_doe, load_doe, save_doe
from edofproj.doe.storage import TabulatedRadialDOE
from edofproj.errors import EdofprojError
from edofproj.fabrication.masks import decompose, depth_from_masks, etch_code, level_from_etched, top_surface_m
from edofproj.fabrication.profile import RadialProfile, check_power_of_two_levels, mask_count

R = 3.5e-3


def random_profile(levels=16, rings=64, seed=0):
    level = np.random.default_rng(seed).integers(0, levels, rings)
    return RadialProfile(
        np.linspace(0, R, rings + 1), level, levels, h2pi_m=1195.9e-9, aperture_radius_m=R, design_wavelength_m=550e-9
    )


def tabulated(doe, tmp_path, samples=256):
    """``doe`` as written to and read back from a design file."""
    save_doe(doe, tmp_path / "design.npz", samples=samples)
    return load_doe(tmp_path / "design.npz")


def test_power_of_two_levels():
    assert [mask_count(n) for n in (2, 4, 8, 16, 32)] == [1, 2, 3, 4, 5]
    for bad in (0, 1, 3, 6, 12, 15):
        with pytest.raises(EdofprojError, match="not a power of two"):
            check_power_of_two_levels(bad)


def test_paper_etch_depths(tmp_path):
    doe = build_doe(apply_overrides(Config(), ["doe.design_wavelength_nm=550"]), "axicon")  # the paper's 550 nm
    profile = RadialProfile.from_doe(tabulated(doe, tmp_path))
    depths_nm = [m.etch_depth_m * 1e9 for m in decompose(profile)]
    np.testing.assert_allclose(depths_nm, [75, 150, 300, 600], rtol=0.01)  # paper: 75/150/300/600 nm
    assert depths_nm[1] == pytest.approx(2 * depths_nm[0]) and depths_nm[3] == pytest.approx(8 * depths_nm[0])
    assert top_surface_m(profile) == pytest.approx(sum(depths_nm) * 1e-9)


@pytest.mark.parametrize("levels", [2, 4, 16])
def test_masks_rebuild_the_profile_exactly(levels):
    profile = random_profile(levels)
    masks = decompose(profile)
    r = profile.ring_centres_m
    etched = np.stack([m.etched(r) for m in masks])
    np.testing.assert_array_equal(level_from_etched(etched, levels), profile.level)
    # height = top - sum of etched depths = level * step
    np.testing.assert_allclose(top_surface_m(profile) - depth_from_masks(r, masks), profile.height_m, atol=1e-15)


def test_etch_convention_level_zero_is_deepest():
    profile = RadialProfile(np.array([0, 1e-3, 2e-3, 3e-3]), np.array([0, 15, 5]), 16, 1.2e-6, 3e-3, 550e-9)
    masks = decompose(profile)
    r = profile.ring_centres_m
    depth = depth_from_masks(r, masks)
    np.testing.assert_allclose(depth / profile.step_m, [15, 0, 10])
    np.testing.assert_array_equal(etch_code([0, 15, 5], 16), [15, 0, 10])
    # level 5 -> code 10 = 0b1010: masks 1 and 3 etch, masks 0 and 2 do not
    assert [bool(m.etched(r[2])) for m in masks] == [False, True, False, True]


def test_adjacent_rings_merge_into_one_annulus():
    # levels 0,0,2,2,1: code 15,15,13,13,14 -> mask 0 (bit 0) etched on rings 0-3, mask 1 on rings 0,1 and 4
    edges = np.arange(6) * 1e-4
    profile = RadialProfile(edges, np.array([0, 0, 2, 2, 1]), 16, 1.2e-6, 5e-4, 550e-9)
    masks = decompose(profile)
    np.testing.assert_allclose(masks[0].annuli_m, [[0, 4e-4]])
    np.testing.assert_allclose(masks[1].annuli_m, [[0, 2e-4], [4e-4, 5e-4]])
    np.testing.assert_allclose(masks[2].annuli_m, [[0, 5e-4]])
    zone_edges, zone_levels = profile.zones()
    np.testing.assert_allclose(zone_edges, [0, 2e-4, 4e-4, 5e-4])
    np.testing.assert_array_equal(zone_levels, [0, 2, 1])


def test_features_and_widths():
    edges = np.arange(6) * 1e-4
    profile = RadialProfile(edges, np.array([15, 14, 14, 15, 14]), 16, 1.2e-6, 5e-4, 550e-9)
    mask0 = decompose(profile)[0]  # bit 0 of the etch code 15 - L is set where L = 14
    np.testing.assert_allclose(mask0.annuli_m, [[1e-4, 3e-4], [4e-4, 5e-4]])
    widths = [(f.etched, round(f.width_m * 1e6, 6)) for f in mask0.features()]
    # central un-etched disk counts with its diameter (200 um), then ring 200 um, gap 100 um, ring 100 um
    assert widths == [(False, 200.0), (True, 200.0), (False, 100.0), (True, 100.0)]
    assert profile.narrowest_zone_m() == pytest.approx(1e-4)


def test_requantization_and_file_levels(tmp_path):
    doe = tabulated(build_doe(Config(), "multifocal"), tmp_path)
    profile16 = RadialProfile.from_doe(doe)
    np.testing.assert_allclose(profile16.height_m, doe.table_height_m.numpy(), atol=1e-15)
    profile4 = RadialProfile.from_doe(doe, levels=4)
    np.testing.assert_array_equal(profile4.level, np.round(profile16.level / 4).astype(int) % 4)
    with pytest.raises(EdofprojError, match="not a power of two"):
        RadialProfile.from_doe(doe, levels=6)
    continuous = TabulatedRadialDOE(np.linspace(0, R, 5), np.zeros(4), R, 550e-9, None)
    with pytest.raises(EdofprojError, match="continuous"):
        RadialProfile.from_doe(continuous)
    with pytest.raises(EdofprojError, match="radial design"):
        RadialProfile.from_doe(build_doe(Config(), "cubic"))
