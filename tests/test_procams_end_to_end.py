"""End to end through the virtual ProCams (issue 6, item 7): patterns -> simulated captures (lens PSF
at 350 mm with v = 500 mm, gamma 2.2, homography + barrel distortion, colour mixing, ambient light,
Gaussian noise, 8-bit) -> geometric and colour calibration -> measured PSF.

Tolerances, and what was measured when they were set (4 camera poses, seeds 0-3):
* PSF L1 = sum|p_est - p_true| / sum p_true < 0.10 per channel (measured 0.041-0.047; noise-limited:
  1.2 % without noise), in-window energy within 0.01 (measured <= 0.0043);
* mixing matrix: max error < 0.5 % of its largest entry (measured 0.01-0.02 %);
* response at the colour samples within 0.005; between them (4 levels per channel, local linear
  interpolation of u^2.2) mean error < 0.04 (measured 0.025), inverse mean < 0.08 (measured 0.056);
* camera map: rms < 0.05 projector px over the image (measured 0.023-0.026), max < 0.1 px inside
  the dot grid (measured 0.043-0.051; up to 0.26 px where it is extrapolated to the image corners).
"""

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from edofproj.config import load_config
from edofproj.doe import build_doe
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.procams.calibration import calibrate, calibration_files
from edofproj.procams.patterns import PatternSpec, build_pattern_set
from edofproj.procams.psf_estimation import bernoulli_files, measure_psf
from edofproj.procams.virtual import VirtualProCams

PROJECTOR_HW = (96, 128)
WINDOW = 21


def l1_error(estimate, truth):
    return float(np.abs(estimate - truth).sum() / truth.sum())


@pytest.fixture(scope="module")
def patterns():
    return build_pattern_set(PatternSpec(width=128, height=96, dot_grid=(6, 8), color_levels=4, seed=0))


@pytest.fixture(scope="module")
def lens_session(patterns):
    torch.set_num_threads(1)
    cfg = load_config(None)
    psf = simulator_from_config(cfg, window=WINDOW).bank(build_doe(cfg, "lens"), [0.35]).psf.numpy()[0]
    manifest, images = patterns
    rig = VirtualProCams.example(PROJECTOR_HW, psf, seed=2, noise_sigma=0.005)
    rng = np.random.default_rng(2)
    captures = {f: rig.capture(images[f], rng) for f in calibration_files(manifest) + bernoulli_files(manifest)}
    calibration = calibrate(manifest, captures)
    return rig, psf, captures, calibration


def test_the_camera_differs_from_the_projector(lens_session):
    rig = lens_session[0]
    assert rig.camera_hw != PROJECTOR_HW
    assert 2.0 < rig.camera_pixels_per_projector_pixel() < 4.0


def test_measured_psf_matches_the_lens_psf(lens_session, patterns):
    rig, psf, captures, calibration = lens_session
    manifest, images = patterns
    estimate = measure_psf(manifest, images, captures, calibration, WINDOW)
    assert estimate.psf.shape == (3, WINDOW, WINDOW)
    for channel in range(3):
        assert l1_error(estimate.psf[channel], psf[channel]) < 0.10
    np.testing.assert_allclose(estimate.energy_in_window, psf.sum(axis=(-1, -2)), atol=0.01)


def test_patch_psfs_match_the_lens_psf(lens_session, patterns):
    rig, psf, captures, calibration = lens_session
    manifest, images = patterns
    estimate = measure_psf(manifest, images, captures, calibration, WINDOW, patch=40)
    assert len(estimate.patch_psfs) == 2
    for patch_psf in estimate.patch_psfs:
        assert l1_error(patch_psf, psf) < 0.15  # half the pixels of the whole image each
    assert l1_error(estimate.psf, psf) < 0.10


def test_mixing_matrix_and_black_level_are_recovered(lens_session):
    rig, _, _, calibration = lens_session
    truth = rig.effective_mixing_matrix
    error = np.abs(calibration.color.mixing_matrix - truth).max() / np.abs(truth).max()
    assert error < 0.005
    np.testing.assert_allclose(calibration.color.black_level, rig.black_capture_level, atol=0.002)


def test_projector_response_is_recovered(lens_session):
    rig, _, _, calibration = lens_session
    color = calibration.color
    np.testing.assert_allclose(color.sample_outputs, rig.normalized_response(color.sample_inputs), atol=0.005)
    queries = np.random.default_rng(5).uniform(0, 1, (3000, 3))
    truth = rig.normalized_response(queries)
    assert np.abs(color.input_to_output(queries) - truth).mean() < 0.04
    assert np.abs(color.output_to_input(truth) - queries).mean() < 0.08


def test_camera_map_is_recovered(lens_session, patterns):
    rig, _, _, calibration = lens_session
    true_x, true_y = rig.true_camera_map()
    camera_map = calibration.camera_map
    error_px = np.hypot(camera_map.map_x - true_x, camera_map.map_y - true_y) / rig.camera_pixels_per_projector_pixel()
    assert np.sqrt(np.mean(error_px**2)) < 0.05
    dots = patterns[0].one("dots").dots
    inside = error_px[
        int(dots[:, 1].min()) : int(dots[:, 1].max()) + 1, int(dots[:, 0].min()) : int(dots[:, 0].max()) + 1
    ]
    assert inside.max() < 0.1


def test_lopsided_hazy_psf_keeps_orientation_and_energy(patterns):
    """A PSF with 20 % haze whose side lobes are unequal (centroid on the axis): a flip, a shift or
    a wrong energy normalization would show."""
    manifest, images = patterns
    c = WINDOW // 2
    psf = np.zeros((3, WINDOW, WINDOW))
    psf[:, c, c], psf[:, c + 1, c + 2], psf[:, c - 2, c - 4] = 0.5, 0.2, 0.1  # centroid 0.2(2,1) + 0.1(-4,-2) = 0
    psf = np.stack([gaussian_filter(channel, 0.7) for channel in psf])
    rig = VirtualProCams.example(PROJECTOR_HW, psf, seed=3, noise_sigma=0.005)
    rng = np.random.default_rng(3)
    captures = {f: rig.capture(images[f], rng) for f in calibration_files(manifest) + bernoulli_files(manifest)}
    estimate = measure_psf(manifest, images, captures, calibrate(manifest, captures), WINDOW)
    assert l1_error(estimate.psf, psf) < 0.10
    np.testing.assert_allclose(estimate.energy_in_window, 0.8, atol=0.01)
    green = estimate.psf[1]
    assert green[c + 1, c + 2] > 5 * green[c - 1, c - 2]  # the strong lobe stays where it is
