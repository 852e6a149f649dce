"""The virtual ProCams on a textured surface, and the surface measured from black and white captures.

Calibration (geometry and colour) is made from captures of the white screen; then the same rig with a
textured surface, an ambient illuminance and camera noise captures the black and the white field (4
frames each). The measured reflectance and ambient are checked against the rig's closed-form ground
truth (:meth:`VirtualProCams.true_surface`), independent of the capture pipeline: median error
<= 1 % of the range [0, 1] away from the image border and depth edges (measured when set: 0.28 % for the
reflectance and 0.20 % for the ambient, flat and depth-map screens alike).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_dilation

from edofproj.errors import EdofprojError
from edofproj.procams.calibration import ProCamsCalibration, calibrate, calibration_files
from edofproj.procams.patterns import PatternSpec, build_pattern_set
from edofproj.procams.surface import measure_surface, surface_capture_files
from edofproj.procams.virtual import VirtualProCams

PROJECTOR_HW = (48, 64)
WINDOW = 9
REPEATS = 4


def gaussian_psf(sigma: float, size: int = WINDOW) -> np.ndarray:
    r2 = (np.arange(size) - size // 2)[:, None] ** 2 + (np.arange(size) - size // 2)[None, :] ** 2
    kernel = np.exp(-r2 / (2 * sigma**2))
    return np.repeat((kernel / kernel.sum())[None], 3, axis=0)


def block_texture(seed: int = 0, block: int = 4, low: float = 0.1) -> np.ndarray:
    """Reflectance of random colour blocks in [low, 1], ``(H, W, 3)``: sharp edges every ``block`` px."""
    H, W = PROJECTOR_HW
    cells = np.random.default_rng(seed).uniform(low, 1.0, (H // block, W // block, 3))
    return np.kron(cells, np.ones((block, block, 1)))


@pytest.fixture(scope="module")
def patterns():
    return build_pattern_set(PatternSpec(width=64, height=48, dot_grid=(5, 7), color_levels=4, seed=0))


@pytest.fixture(scope="module")
def white_calibration(patterns):
    torch.set_num_threads(1)
    manifest, images = patterns
    rig = VirtualProCams.example(PROJECTOR_HW, gaussian_psf(1.0), seed=3, noise_sigma=0.005)
    rng = np.random.default_rng(3)
    return calibrate(manifest, {f: rig.capture(images[f], rng) for f in calibration_files(manifest)})


def measure(rig, calibration, patterns, seed=0):
    manifest, images = patterns
    black, white = surface_capture_files(manifest)
    rng = np.random.default_rng(seed)
    blacks = [rig.capture(images[black], rng) for _ in range(REPEATS)]
    whites = [rig.capture(images[white[0]], rng) for _ in range(REPEATS)]
    return measure_surface(calibration, blacks, whites)


def away_from(edges: np.ndarray, margin: int) -> np.ndarray:
    """Pixels farther than ``margin`` from the image border and from ``edges`` (bool (H, W))."""
    keep = ~binary_dilation(edges, iterations=margin)
    keep[:margin] = keep[-margin:] = False
    keep[:, :margin] = keep[:, -margin:] = False
    return keep


def check_against_truth(measured, rig, keep):
    rho, ambient = rig.true_surface()
    rho_error = np.abs(measured.reflectance - rho)[keep]
    ambient_error = np.abs(measured.ambient - ambient)[keep]
    assert np.median(rho_error) <= 0.01, np.median(rho_error)
    assert np.median(ambient_error) <= 0.01, np.median(ambient_error)
    # and the measurement is not trivially small: the texture spans most of [0, 1]
    assert np.ptp(measured.reflectance[keep]) > 0.7
    return float(np.median(rho_error)), float(np.median(ambient_error))


def test_flat_textured_surface_is_measured(white_calibration, patterns):
    rig = VirtualProCams.example(
        PROJECTOR_HW,
        gaussian_psf(1.5),
        seed=3,
        noise_sigma=0.005,
        reflectance=block_texture(1),
        surface_ambient=(0.05, 0.02, 0.08),
    )
    measured = measure(rig, white_calibration, patterns)
    keep = away_from(np.zeros(PROJECTOR_HW, bool), WINDOW // 2 + 2)
    check_against_truth(measured, rig, keep)
    # the model closes: what the calibration sees of a pattern is s ⊙ (PSF ⊛ u^gamma) + a (here a uniform grey)
    grey = np.full((*PROJECTOR_HW, 3), 0.6)
    seen = white_calibration.color.camera_to_output(
        white_calibration.camera_map.warp(np.mean([rig.capture(grey, np.random.default_rng(i)) for i in range(4)], 0)),
        np.zeros(3),
    )
    rho, ambient = rig.true_surface()
    predicted = rho * 0.6**2.2 + ambient
    assert np.median(np.abs(seen - predicted)[keep]) <= 0.01
    # the measured surface as the forward model's Surface gives the same prediction
    light = torch.full((1, 3, *PROJECTOR_HW), 0.6**2.2)
    modelled = measured.as_surface().appearance(light)[0].permute(1, 2, 0).numpy()
    assert np.median(np.abs(seen - modelled)[keep]) <= 0.01


def test_depth_map_surface_is_measured_away_from_depth_edges(white_calibration, patterns):
    H, W = PROJECTOR_HW
    depth = np.full((H, W), 0.6)
    depth[:, : W // 2] = 0.4  # a step: near on the left
    rig = VirtualProCams.example(
        PROJECTOR_HW,
        np.stack([gaussian_psf(2.0), gaussian_psf(0.8)]),
        seed=3,
        noise_sigma=0.005,
        depth_map_m=depth,
        layer_depths_m=np.array([0.4, 0.6]),
        reflectance=block_texture(2),
        surface_ambient=0.03,
    )
    measured = measure(rig, white_calibration, patterns, seed=1)
    edges = np.zeros((H, W), bool)
    edges[:, W // 2 - 1 : W // 2 + 1] = True
    keep = away_from(edges, WINDOW // 2 + 2)
    check_against_truth(measured, rig, keep)
    # at the depth edge the full field is not uniform: the measured gain differs from the reflectance there
    rho, _ = rig.true_surface()
    near_edge = binary_dilation(edges, iterations=2)
    assert np.median(np.abs(measured.reflectance - rho)[near_edge]) > np.median(
        np.abs(measured.reflectance - rho)[keep]
    )


def test_surface_is_saved_with_the_calibration_and_required_by_surface_commands(white_calibration, tmp_path):
    with pytest.raises(EdofprojError, match="made without the surface captures") as err:
        white_calibration.require_surface("compensating for the surface")
    assert "\n" not in str(err.value)
    H, W = PROJECTOR_HW
    rho = block_texture(3).astype(np.float32)
    ambient = np.full((H, W, 3), 0.04, np.float32)
    calibration = white_calibration.with_surface(rho, ambient)
    calibration.save(tmp_path / "calib.npz")
    loaded = ProCamsCalibration.load(tmp_path / "calib.npz")
    got_rho, got_ambient = loaded.require_surface()
    np.testing.assert_array_equal(got_rho, rho)
    np.testing.assert_array_equal(got_ambient, ambient)
    white_calibration.save(tmp_path / "plain.npz")
    assert not ProCamsCalibration.load(tmp_path / "plain.npz").has_surface
    # a damaged file: one line
    with np.load(tmp_path / "calib.npz") as data:
        arrays = dict(data)
    arrays["surface_reflectance"] = arrays["surface_reflectance"] * 2
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(EdofprojError, match=r"bad.npz' has a reflectance outside \[0, 1\]"):
        ProCamsCalibration.load(tmp_path / "bad.npz")
    del arrays["surface_ambient"]
    np.savez(tmp_path / "half.npz", **arrays)
    with pytest.raises(EdofprojError, match="has 'surface_reflectance' without surface_ambient"):
        ProCamsCalibration.load(tmp_path / "half.npz")
    with pytest.raises(EdofprojError, match="not \\(48, 64, 3\\)"):
        white_calibration.with_surface(rho[:10], ambient)


def test_a_surface_brighter_than_the_calibrations_white_is_warned(white_calibration, patterns):
    """Colour calibrated on a grey surface: the object looks brighter than 'white' -- warned, clipped to 1."""
    rig = VirtualProCams.example(
        PROJECTOR_HW, gaussian_psf(1.0), seed=3, noise_sigma=0.0, reflectance=np.full((*PROJECTOR_HW, 3), 1.0)
    )
    grey = white_calibration.color
    darker = type(grey)(grey.mixing_matrix * 0.5, grey.black_level, grey.sample_inputs, grey.sample_outputs)
    calibration = ProCamsCalibration(white_calibration.camera_map, darker, white_calibration.black_image)
    with pytest.warns(UserWarning, match="reflects more than the calibration's white"):
        measured = measure(rig, calibration, patterns)
    assert measured.reflectance.max() <= 1.0


def test_swapped_white_and_black_captures_are_refused(white_calibration, patterns):
    """The white field darker than the black one: the reflectance would clip to 0 everywhere."""
    rig = VirtualProCams.example(PROJECTOR_HW, gaussian_psf(1.0), seed=3, reflectance=block_texture(1))
    manifest, images = patterns
    black, white = surface_capture_files(manifest)
    rng = np.random.default_rng(0)
    with pytest.raises(EdofprojError, match=r"the white field is darker than the black one at 100 % .* swapped"):
        measure_surface(white_calibration, [rig.capture(images[white[0]], rng)], [rig.capture(images[black], rng)])


@pytest.mark.parametrize("rho, ambient", [(0.0, 0.0), (0.0, 0.3), (0.005, 0.0)])
def test_a_surface_that_cannot_show_an_image_is_not_recorded(white_calibration, patterns, rho, ambient):
    """A black object (or one lit only by the room): one line, not a zero surface in calib.npz."""
    rig = VirtualProCams.example(
        PROJECTOR_HW, gaussian_psf(1.0), seed=3, reflectance=np.full((*PROJECTOR_HW, 3), rho), surface_ambient=ambient
    )
    with pytest.raises(EdofprojError, match=r"^the surface measured cannot show an image: .* is 0\.0[01]\d .* black"):
        measure(rig, white_calibration, patterns)


def test_a_camera_moved_between_the_sessions_is_measured_to_a_tenth_of_a_pixel(patterns):
    """camera_shift_px of the full field less black: a still camera reads <= 0.15 camera px (other noise,
    another texture than the white screen's), a move of d camera px reads d within 0.15."""
    import dataclasses

    from edofproj.procams.surface import camera_shift_px

    manifest, images = patterns
    black, white = surface_capture_files(manifest)

    def session(rig, seed):
        rng = np.random.default_rng(seed)
        return rig.capture(images[black], rng), [rig.capture(images[white[0]], rng)]

    screen = VirtualProCams.example(PROJECTOR_HW, gaussian_psf(1.0), seed=3, noise_sigma=0.005)
    textured = dataclasses.replace(screen, reflectance=block_texture(1), surface_ambient=(0.05, 0.05, 0.05))
    reference = session(screen, 0)
    assert np.hypot(*camera_shift_px(reference, session(textured, 1))) <= 0.15
    for dy, dx in ((0.0, 1.0), (-1.2, 1.6), (3.0, 0.0)):
        moved = dataclasses.replace(
            textured, homography=np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1.0]]) @ textured.homography
        )
        shift = camera_shift_px(reference, session(moved, 2))
        np.testing.assert_allclose(-shift, (dy, dx), atol=0.15)
