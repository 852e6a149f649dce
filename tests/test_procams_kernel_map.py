"""The kernel map (``procams psf-map --model rank-profile``): dots of known rank profiles on a virtual rig
are recovered at every node, the decoded map's offset is found, the file round-trips, every consumer of a
PSF map file takes it, and bad input fails in one line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.procams.kernel_map import KernelMap, choose_smooth_px, measure_kernel_map
from edofproj.procams.lab_kernels import orbits
from edofproj.procams.measured_blur import map_file_blur
from edofproj.procams.psf_map import DotGrid, PSFMap, save_psf_maps
from edofproj.procams.structured_light import CorrespondenceMap
from virtual_rigs import write_dots_lab

H, W, S, HALF = 72, 96, 12, 5


def ring_window(levels: np.ndarray) -> np.ndarray:
    """``(11, 11)``: ``levels[k]`` on the ``k``-th ring, rings ordered (0,0), (1,0), (1,1), (2,0), ...: the
    ring of offset ``(dy, dx)`` with ``i = max(|dy|, |dx|)``, ``j = min`` is ``i (i + 1) / 2 + j``."""
    out = np.zeros((2 * HALF + 1, 2 * HALF + 1))
    for dy in range(-HALF, HALF + 1):
        for dx in range(-HALF, HALF + 1):
            i, j = max(abs(dy), abs(dx)), min(abs(dy), abs(dx))
            out[HALF + dy, HALF + dx] = levels[i * (i + 1) // 2 + j]
    return out


def capture_of(windows_by_column, shift_px: int = 0) -> np.ndarray:
    """A camera = projector capture of a 12-px dot grid, each dot drawn as its column's window (8-bit,
    grey), the camera seeing the projector shifted by ``shift_px`` (the decoded map adds it back)."""
    grid = DotGrid.covering((H, W), (S, S))
    image = np.zeros((H + 2 * HALF, W + 2 * HALF))
    for y in grid.ys.astype(int):
        for x in grid.xs.astype(int):
            image[y : y + 2 * HALF + 1, x : x + 2 * HALF + 1] += windows_by_column(x)
    image = image[HALF : HALF + H, HALF : HALF + W]
    return np.repeat(np.rint(image).astype(np.uint8)[..., None], 3, axis=-1)


def identity_map(shift_px: int = 0) -> CorrespondenceMap:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return CorrespondenceMap(proj_x=u + shift_px, proj_y=v + shift_px, projector_hw=(H, W))


# 21 distinct levels falling with the ring, and a narrower profile with 6 levels (zeros beyond)
WIDE = np.linspace(200, 20, 21).round()
NARROW = np.concatenate([[250, 180, 120, 70, 30, 10], np.zeros(15)])


def expected_kernel(levels: np.ndarray) -> np.ndarray:
    window = ring_window(levels)
    return window / window.sum()


def test_every_node_recovers_the_dots_known_profile():
    # dots 12 px apart with windows of 11 px: each window holds only its own dot
    capture = capture_of(lambda x: ring_window(WIDE))
    kmap = measure_kernel_map([(capture, "mean")], identity_map(), DotGrid.covering((H, W), (S, S)))
    assert kmap.channels == ("red", "green", "blue")
    assert kmap.kernels.shape == (3, len(kmap.ys), len(kmap.xs), 11, 11)
    np.testing.assert_allclose(kmap.kernels, np.broadcast_to(expected_kernel(WIDE), kmap.kernels.shape), atol=1e-12)
    np.testing.assert_allclose(kmap.offset_px, [0.0, 0.0], atol=1e-12)


def test_a_profile_that_changes_across_the_field_is_kept_away_from_the_change():
    capture = capture_of(lambda x: ring_window(WIDE if x < W // 2 else NARROW))
    kmap = measure_kernel_map([(capture, "mean")], identity_map(), DotGrid.covering((H, W), (S, S)), smooth_px=24)
    left, right = kmap.xs + 12 < W // 2, kmap.xs - 12 >= W // 2  # nodes whose box holds one kind of dot only
    assert left.any() and right.any()
    np.testing.assert_allclose(
        kmap.kernels[:, :, left], np.broadcast_to(expected_kernel(WIDE), kmap.kernels[:, :, left].shape), atol=1e-12
    )
    np.testing.assert_allclose(
        kmap.kernels[:, :, right], np.broadcast_to(expected_kernel(NARROW), kmap.kernels[:, :, right].shape), atol=1e-12
    )


def test_the_decoded_maps_offset_is_estimated_and_removed():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    corr = CorrespondenceMap(proj_x=u + 1.0, proj_y=v + 1.0, projector_hw=(H, W))  # a 1-based phase origin
    kmap = measure_kernel_map(
        [(capture_of(lambda x: ring_window(WIDE)), "mean")], corr, DotGrid.covering((H, W), (S, S))
    )
    assert np.all((kmap.offset_px >= 0.5) & (kmap.offset_px < 1.5))  # rounds to the shift of one pixel
    interior = kmap.kernels[:, 1:-1, 1:-1]  # the first row and column of dots lose their top and left (the shift)
    np.testing.assert_allclose(interior, np.broadcast_to(expected_kernel(WIDE), interior.shape), atol=1e-12)


def test_round_trip_and_every_consumer_takes_the_file(tmp_path):
    kmap = measure_kernel_map(
        [(capture_of(lambda x: ring_window(NARROW)), "mean")], identity_map(), DotGrid.covering((H, W), (S, S))
    )
    path = tmp_path / "k.npz"
    kmap.save(path)
    back = KernelMap.load(path)
    np.testing.assert_array_equal(back.kernels, kmap.kernels)
    assert back.channels == kmap.channels and back.projector_hw == (H, W)
    op = map_file_blur(path)
    assert (op.height, op.width, op.channels) == (H, W, 3)
    # one lit pixel far from the edges spreads as the recovered kernel
    import torch

    x = torch.zeros(1, 3, H, W, dtype=torch.float64)
    x[..., 36, 48] = 1.0
    spread = op.forward(x)[0, 0, 36 - HALF : 36 + HALF + 1, 48 - HALF : 48 + HALF + 1].numpy()
    np.testing.assert_allclose(spread, expected_kernel(NARROW), atol=1e-9)
    # a Gaussian PSF map file still gives its own blur
    cov = np.broadcast_to(np.diag([1.0, 2.0]), (2, 2, 2, 2)).copy()
    gauss = PSFMap(np.array([0.0, W - 1.0]), np.array([0.0, H - 1.0]), cov, np.zeros(2), np.ones((2, 2), bool), (H, W))
    save_psf_maps(tmp_path / "g.npz", [gauss])
    assert map_file_blur(tmp_path / "g.npz").channels == 1


def test_bad_files_and_captures_fail_in_one_line(tmp_path):
    kmap = measure_kernel_map(
        [(capture_of(lambda x: ring_window(WIDE)), "mean")], identity_map(), DotGrid.covering((H, W), (S, S))
    )
    kmap.kernels[0, 0, 0, 5, 5] = -1.0
    kmap.save(tmp_path / "bad.npz")
    with pytest.raises(EdofprojError, match="not non-negative and normalized"):
        KernelMap.load(tmp_path / "bad.npz")
    cov = np.broadcast_to(np.eye(2), (2, 2, 2, 2)).copy()
    save_psf_maps(
        tmp_path / "g.npz",
        [PSFMap(np.array([0.0, 9.0]), np.array([0.0, 9.0]), cov, np.zeros(2), np.ones((2, 2), bool), (10, 10))],
    )
    with pytest.raises(EdofprojError, match="is not a kernel map"):
        KernelMap.load(tmp_path / "g.npz")
    with pytest.raises(EdofprojError, match="is a kernel map .* needs a Gaussian PSF map"):
        PSFMap.load(tmp_path / "bad.npz")  # what procams predict reads
    sixteen = capture_of(lambda x: ring_window(WIDE)).astype(np.uint16)
    with pytest.raises(EdofprojError, match="8-bit RGB"):
        measure_kernel_map([(sixteen, "mean")], identity_map(), DotGrid.covering((H, W), (S, S)))
    with pytest.raises(EdofprojError, match="no dot is seen"):
        measure_kernel_map([(np.zeros((H, W, 3), np.uint8), "mean")], identity_map(), DotGrid.covering((H, W), (S, S)))


@pytest.fixture()
def lab(tmp_path):
    cv2.imwrite(str(tmp_path / "dots.png"), capture_of(lambda x: ring_window(WIDE)))
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros((H, W, 3), np.uint8))
    identity_map().save(tmp_path / "map.npz")
    write_dots_lab(tmp_path, (H, W), S, background="black")
    return tmp_path


def test_the_command_writes_a_kernel_map_that_compensate_uses(lab, capsys):
    base = ["procams", "psf-map", "--lab", str(lab / "lab.json"), "--dots", "dots", "--map", str(lab / "map.npz")]
    assert main([*base, "--model", "rank-profile", "--background", "black", "--out", str(lab / "k.npz")]) == 0
    out = capsys.readouterr().out
    assert "kernel map of red, green, blue" in out and "box by leave-one-out: " in out
    np.testing.assert_allclose(KernelMap.load(lab / "k.npz").kernels[0, 2, 2], expected_kernel(WIDE), atol=1e-12)
    target = np.full((H, W, 3), 128, np.uint8)
    cv2.imwrite(str(lab / "t.png"), target)
    argv = ["compensate", "--psf-map", str(lab / "k.npz"), "--image", str(lab / "t.png"), "--method", "cls"]
    assert main([*argv, "--iterations", "3", "--nsr", "0.01", "--out", str(lab / "c.png")]) == 0
    assert cv2.imread(str(lab / "c.png")).shape == (H, W, 3)
    for extra, message in (
        (
            ["--background", "black", "--out", str(lab / "x.npz")],
            "--background and --smooth-px go with --model rank-profile",
        ),
        (["--model", "rank-profile", "--figure", str(lab / "f.png"), "--out", str(lab / "x.npz")], "--figure"),
        (
            ["--model", "rank-profile", "--every", "2", "--out", str(lab / "x.npz")],
            "--every goes with --model gaussian",
        ),
    ):
        assert main([*base, *extra]) != 0
        assert message in capsys.readouterr().err
        assert not (lab / "x.npz").exists()


def test_leave_one_out_picks_a_large_box_for_noise_and_a_small_one_for_a_fast_change():
    grid = DotGrid.covering((12 * 40, 12 * 40), (S, S))
    rng = np.random.default_rng(1)
    seen = np.ones((grid.rows, grid.cols), bool)
    base = expected_kernel(WIDE)[HALF, HALF:]  # any positive profile; only differences matter
    flat = np.broadcast_to(np.resize(base, 21), (grid.rows, grid.cols, 21))
    noisy = flat + rng.normal(0, 1e-3, flat.shape)  # one blur everywhere, each dot's estimate scattered
    side, errors = choose_smooth_px([noisy], [seen], grid)
    assert side == max(errors) == 15 * S
    # i.i.d. scatter: the error of a box of N dots is sigma^2 (1 + 1 / (N - 1)) per value, in closed form
    sizes = np.array([len(o) for o in orbits(HALF)])
    assert errors[3 * S] == pytest.approx(1e-6 * sizes.sum() * (1 + 1 / 8), rel=0.1)
    stripes = np.where((np.arange(grid.cols) // 2 % 2 == 0)[None, :, None], flat, 0.5 * flat)  # changes every 2 dots
    side, _ = choose_smooth_px([stripes + rng.normal(0, 1e-5, flat.shape)], [seen], grid)
    assert side == 3 * S
