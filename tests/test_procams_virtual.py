"""The virtual ProCams: its screen follows edofproj.imaging exactly, its geometry inverts, its camera
adds the stated noise, and it writes the ground truth."""

import json

import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.imaging import project, render_depth_map
from edofproj.optics.psf_bank import PSFBank
from edofproj.procams.capture_io import read_rgb
from edofproj.procams.patterns import PatternManifest, PatternSpec, build_pattern_set
from edofproj.procams.virtual import VirtualProCams, simulate_captures

HW = (40, 56)


def box_psf(size, energy=0.9):
    psf = np.zeros((3, 7, 7))
    lo = 3 - size // 2
    psf[:, lo : lo + size, lo : lo + size] = energy / size**2
    return psf


def test_screen_is_imaging_project_inside_the_image():
    rig = VirtualProCams.example(HW, box_psf(3), seed=0)
    image = np.random.default_rng(0).uniform(0, 1, HW + (3,))
    screen = rig.screen_image(image)
    m = rig.canvas_margin_px
    output = torch.from_numpy(rig.projector_output(image).transpose(2, 0, 1))[None]
    expected = project(output, torch.from_numpy(rig.psf)).numpy()[0].transpose(1, 2, 0)
    np.testing.assert_allclose(screen[m:-m, m:-m], expected, atol=1e-12)
    assert screen[m - 1, m:-m].max() > 0.05  # the direct light spills past the border onto the margin
    np.testing.assert_allclose(screen[0], 0.0, atol=1e-12)  # no haze beyond the image


def test_screen_with_a_depth_map_is_render_depth_map_inside_the_image():
    layers = np.array([0.3, 0.5])
    psf = np.stack([box_psf(5), box_psf(1, energy=1.0)])
    depth = np.tile(np.linspace(0.3, 0.5, HW[1]), (HW[0], 1))
    rig = VirtualProCams.example(HW, psf, seed=0, depth_map_m=depth, layer_depths_m=layers)
    image = np.random.default_rng(1).uniform(0, 1, HW + (3,))
    m = rig.canvas_margin_px
    output = torch.from_numpy(rig.projector_output(image).transpose(2, 0, 1))[None]
    expected = render_depth_map(output, depth, torch.from_numpy(psf), layers=list(layers)).numpy()[0]
    np.testing.assert_allclose(rig.screen_image(image)[m:-m, m:-m], expected.transpose(1, 2, 0), atol=1e-12)


def test_projector_and_camera_coordinates_invert():
    rig = VirtualProCams.example(HW, box_psf(3), seed=4, radial_k1=0.05)
    x, y = np.meshgrid(np.linspace(-0.5, HW[1] - 0.5, 9), np.linspace(-0.5, HW[0] - 0.5, 7))
    u, v = rig.projector_points_to_camera(x, y)
    back_x, back_y = rig.camera_points_to_projector(u, v)
    np.testing.assert_allclose(back_x, x, atol=1e-9)
    np.testing.assert_allclose(back_y, y, atol=1e-9)
    assert rig.camera_hw != HW


def test_camera_sees_the_mixed_colour_with_the_stated_noise():
    rig = VirtualProCams.example(HW, box_psf(3), seed=1, noise_sigma=0.01)
    capture = rig.capture(np.full(HW + (3,), 1.0), np.random.default_rng(0))
    assert capture.shape == rig.camera_hw + (3,)
    np.testing.assert_array_equal(capture * 255, np.round(capture * 255))  # 8-bit
    u, v = rig.projector_points_to_camera(np.array([HW[1] / 2]), np.array([HW[0] / 2]))
    centre = capture[int(v[0]) - 10 : int(v[0]) + 10, int(u[0]) - 10 : int(u[0]) + 10].reshape(-1, 3)
    expected = rig.effective_mixing_matrix.sum(axis=1) + rig.black_capture_level  # white = black + M_eff 1
    np.testing.assert_allclose(centre.mean(axis=0), expected, atol=0.003)
    np.testing.assert_allclose(centre.std(axis=0), 0.01, rtol=0.15)
    assert np.all(capture[:3, :3] < 0.06)  # outside the projected image: ambient light only


def test_simulate_writes_captures_and_ground_truth(tmp_path):
    manifest, images = build_pattern_set(
        PatternSpec(width=HW[1], height=HW[0], bernoulli_count=1, dot_grid=(2, 3), color_levels=2)
    )
    patterns = tmp_path / "patterns"
    patterns.mkdir()
    from edofproj.procams.capture_io import write_rgb_png
    from edofproj.procams.patterns import manifest_json_text

    for name, image in images.items():
        write_rgb_png(patterns / name, image)
    (patterns / "manifest.json").write_text(manifest_json_text(manifest))
    rig = VirtualProCams.example(HW, box_psf(3), seed=0, depth_m=0.4, pixel_pitch_m=3e-4)
    out = tmp_path / "captures"
    simulate_captures(rig, patterns, out, seed=3)
    for entry in PatternManifest.load(patterns).entries:
        assert read_rgb(out / entry.file).shape == rig.camera_hw + (3,)
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth["gamma"] == [2.2, 2.2, 2.2] and truth["depth_mm"] == pytest.approx(400)
    arrays = np.load(out / "ground_truth.npz")
    np.testing.assert_allclose(arrays["camera_map_x"], rig.true_camera_map()[0])
    bank = PSFBank.load(out / "true_psf.npz")
    np.testing.assert_allclose(bank.psf.numpy()[0], rig.psf[0], atol=1e-7)
    assert json.loads((out / "captures.json").read_text())["depth_mm"] == pytest.approx(400)
    with pytest.raises(EdofprojError, match="exists and is not empty"):
        simulate_captures(rig, patterns, out)


def test_bad_rigs_raise_one_line():
    with pytest.raises(EdofprojError, match="RGB PSFs"):
        VirtualProCams.example(HW, np.ones((1, 4, 4)))
    with pytest.raises(EdofprojError, match="does not see the whole projector image"):
        VirtualProCams.example(HW, box_psf(3), fill=1.2)
