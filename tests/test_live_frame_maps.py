"""The per-frame tables of a calibration (procams/frame_maps.py) against closed forms and the
direct computations they replace."""

import dataclasses
import threading

import numpy as np
import pytest
import torch

from edofproj.errors import EdofprojError
from edofproj.procams.color import ColorCalibration, ResponseLUT
from edofproj.procams.frame_maps import (
    MAP_STEPS_PER_PIXEL,
    ChannelInverseTable,
    Rectifier,
    TrilinearInverseTable,
    inverse_response_table,
    separable_response,
)
from edofproj.procams.geometry import CameraMap

LEVELS = np.round(np.linspace(0, 255, 6)) / 255


def grid_inputs(levels=LEVELS):
    return np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)


def gamma_color(gammas=(2.2, 2.2, 2.2)):
    inputs = grid_inputs()
    return ColorCalibration(np.eye(3), np.zeros(3), inputs, inputs ** np.asarray(gammas))


def test_separable_response_is_found_and_cross_talk_is_not():
    separable, spread = separable_response(gamma_color((2.2, 1.8, 2.4)))
    assert separable and spread < 1e-12
    inputs = grid_inputs()
    crossed = inputs**2.2 + 0.05 * inputs[:, [1, 2, 0]]  # each channel leaks 5 % of the next one's input
    assert not separable_response(ColorCalibration(np.eye(3), np.zeros(3), inputs, crossed))[0]
    scattered = np.random.default_rng(0).uniform(size=(40, 3))  # not a grid: nothing to group
    assert not separable_response(ColorCalibration(np.eye(3), np.zeros(3), scattered, scattered**2.2))[0]


def test_channel_table_inverts_gamma_curves_per_channel():
    """Closed form: the inverse of o = u^gamma is u = o^(1/gamma), channel by channel."""
    gammas = np.array([2.2, 1.8, 2.4])
    table = ChannelInverseTable.from_color(gamma_color(tuple(gammas)))
    light = torch.rand(50, 60, 3, generator=torch.Generator().manual_seed(1))
    inputs = table.apply(light).numpy()
    error = np.abs(inputs - light.numpy() ** (1 / gammas))
    assert error.mean() < 0.002  # a monotone cubic through 6 levels; the local linear 3-D table: 0.03
    bright = light.numpy() > 0.05  # away from black, where o^(1/gamma) is steepest
    assert error[bright].max() < 0.01
    # the ends and the clamp: o <= 0 -> 0 and o >= 1 -> 1, NaN refused
    ends = table.apply(torch.tensor([[[-0.5, 0.0, 1.0], [1.0, 2.0, 0.0]]])).numpy()
    np.testing.assert_allclose(ends, [[[0, 0, 1], [1, 1, 0]]], atol=1e-6)
    with pytest.raises(EdofprojError, match="NaN"):
        table.apply(torch.full((2, 2, 3), float("nan")))


def test_channel_table_writes_into_the_buffer_given():
    table = ChannelInverseTable.from_color(gamma_color())
    light = torch.rand(4, 5, 3)
    out = torch.empty(4, 5, 3)
    assert table.apply(light, out=out) is out
    torch.testing.assert_close(out, table.apply(light))
    strided = light.permute(2, 0, 1).contiguous().permute(1, 2, 0)  # the network's (C, H, W) output seen as HWC
    torch.testing.assert_close(table.apply(strided), table.apply(light))


def test_trilinear_table_agrees_with_grid_sample():
    """The gather-based trilinear reading equals ResponseLUT's grid_sample on the same table, and
    is exact for an affine map (which also pins the axis order)."""
    rng = np.random.default_rng(2)
    A = np.array([[0.9, 0.2, -0.1], [0.05, 0.7, 0.3], [-0.2, 0.1, 0.6]])
    affine = ResponseLUT.from_function(lambda v: v @ A.T + 0.01, size=9)
    light = rng.uniform(size=(7, 9, 3)).astype(np.float32)
    np.testing.assert_allclose(
        TrilinearInverseTable(affine.table).apply(torch.from_numpy(light)).numpy(), light @ A.T + 0.01, atol=1e-5
    )
    for size in (5, 65):  # 65: the default table, where float32 positions reach S^2 = 4225
        curved = ResponseLUT(rng.uniform(size=(size, size, size, 3)))
        reference = curved(torch.from_numpy(light).permute(2, 0, 1)[None])[0].permute(1, 2, 0)
        table = TrilinearInverseTable(curved.table)
        assert table.tolerance < (1e-5 if size == 5 else 5e-4)
        torch.testing.assert_close(table.apply(torch.from_numpy(light)), reference, atol=table.tolerance, rtol=0)


def test_inverse_response_table_chooses_by_separability():
    assert isinstance(inverse_response_table(gamma_color(), 9), ChannelInverseTable)
    inputs = grid_inputs(np.linspace(0, 1, 3))
    crossed = ColorCalibration(np.eye(3), np.zeros(3), inputs, inputs**2.2 + 0.05 * inputs[:, [1, 2, 0]])
    assert isinstance(inverse_response_table(crossed, 9), TrilinearInverseTable)


def test_rectifier_is_the_direct_rectification():
    """Folding the black image and the unmixing into one offset and one 3x3 transform gives
    o = M^-1 (c(q(x)) - c_black(q(x))) as computed directly (float32 rounding apart)."""
    rng = np.random.default_rng(3)
    H, W, Hc, Wc = 12, 16, 30, 40
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    camera_map = CameraMap(
        map_x=1.9 * x + 0.3 * y + 2.2, map_y=1.7 * y + 0.1 * x + 1.6,
        homography=np.eye(3), dots_proj=np.zeros((0, 2)), dots_cam=np.zeros((0, 2)), camera_hw=(Hc, Wc),
    )  # fmt: skip
    mixing = np.array([[0.8, 0.1, 0.05], [0.1, 0.7, 0.1], [0.02, 0.15, 0.9]])
    color = ColorCalibration(mixing, np.full(3, 0.02), grid_inputs(), grid_inputs() ** 2.2)
    black = rng.uniform(0.01, 0.05, (H, W, 3))
    frame = rng.uniform(size=(Hc, Wc, 3)).astype(np.float32)
    direct = color.camera_to_output(camera_map.warp(frame), black)
    rectifier = Rectifier(camera_map, color, black)
    out = np.empty((H, W, 3), np.float32)
    assert rectifier(frame, out=out) is out
    np.testing.assert_allclose(out, direct, atol=1e-5)
    with pytest.raises(EdofprojError, match="is 12x16 pixels, the calibrated camera 30x40"):
        rectifier(frame[:12, :16])


def slanted_map(H=12, W=16, Hc=30, Wc=40):
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    return CameraMap(
        map_x=1.9 * x + 0.3 * y + 2.2, map_y=1.7 * y + 0.1 * x + 1.6,
        homography=np.eye(3), dots_proj=np.zeros((0, 2)), dots_cam=np.zeros((0, 2)), camera_hw=(Hc, Wc),
    )  # fmt: skip


@pytest.mark.parametrize("uniform_black", [True, False])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_integer_frames_are_warped_as_counts(dtype, uniform_black):
    """A camera's integer counts are rectified without converting the camera frame: the result is
    the direct rectification of ``counts / max(dtype)`` within the stated tolerance (half a count
    through ``M^-1``); a uniform black level is folded into the transform, a varying one subtracted."""
    rng = np.random.default_rng(4)
    camera_map = slanted_map()
    mixing = np.array([[0.8, 0.1, 0.05], [0.1, 0.7, 0.1], [0.02, 0.15, 0.9]])
    color = ColorCalibration(mixing, np.full(3, 0.02), grid_inputs(), grid_inputs() ** 2.2)
    black = np.broadcast_to([0.02, 0.03, 0.01], (12, 16, 3)) if uniform_black else rng.uniform(0.01, 0.05, (12, 16, 3))
    top = np.iinfo(dtype).max
    counts = rng.integers(0, top + 1, size=(30, 40, 3)).astype(dtype)
    rectifier = Rectifier(camera_map, color, black)
    steps = MAP_STEPS_PER_PIXEL  # integer frames are read at positions rounded to 1/32 pixel
    rounded = dataclasses.replace(
        camera_map, map_x=np.round(camera_map.map_x * steps) / steps, map_y=np.round(camera_map.map_y * steps) / steps
    )
    direct = color.camera_to_output(rounded.warp(counts.astype(np.float64) / top), black)
    assert rectifier.uniform_black == uniform_black
    out = np.empty((12, 16, 3), np.float32)
    assert rectifier(counts, out=out) is out
    tolerance = rectifier.integer_warp_tolerance(dtype)
    assert tolerance == pytest.approx(np.abs(np.linalg.inv(mixing)).sum(axis=1).max() * 0.5 / top)
    assert np.abs(out - direct).max() <= tolerance + 1e-5
    # the float frame of the same counts, at the exact positions: float32 rounding only
    exact = color.camera_to_output(camera_map.warp(counts.astype(np.float64) / top), black)
    np.testing.assert_allclose(rectifier((counts / top).astype(np.float32)), exact, atol=1e-5)
    with pytest.raises(EdofprojError, match="contiguous"):
        rectifier(counts, out=np.empty((12, 16, 3), np.float64))


def test_channel_table_is_the_nearest_bin_for_any_leading_shape():
    """u_c = T_c[round(clip(o_c, 0, 1) (N - 1))] as numpy computes it from the table, for a batch
    (B, H, W, 3), a strided output buffer, and the same buffers reused for a second input."""
    table = ChannelInverseTable(np.random.default_rng(5).uniform(size=(3, 1000)))
    for seed in (6, 7):
        light = torch.rand(2, 5, 7, 3, generator=torch.Generator().manual_seed(seed)) * 1.2 - 0.1
        bins = np.clip(np.rint(np.clip(light.numpy(), 0, 1) * 999), 0, 999).astype(int)
        expected = table.table[np.arange(3), bins]
        np.testing.assert_array_equal(table.apply(light).numpy(), expected)
        strided = torch.empty(3, 2, 5, 7).permute(1, 2, 3, 0)
        assert table.apply(light, out=strided) is strided
        np.testing.assert_array_equal(strided.numpy(), expected)
        planar = light.permute(0, 3, 1, 2).contiguous().permute(0, 2, 3, 1)  # a (B, 3, H, W) output seen as HWC
        np.testing.assert_array_equal(table.apply(planar).numpy(), expected)
        np.testing.assert_array_equal(table.apply(light.double()).numpy(), expected)
    with pytest.raises(EdofprojError, match="2 <= N <= 65536"):
        ChannelInverseTable(np.zeros((3, 2**16 + 1)))


def test_trilinear_table_reuses_its_buffers_correctly():
    """Two inputs of the same shape read through the same buffers give each its own exact affine
    value; infinite light is refused."""
    A = np.array([[0.9, 0.2, -0.1], [0.05, 0.7, 0.3], [-0.2, 0.1, 0.6]])
    table = TrilinearInverseTable(ResponseLUT.from_function(lambda v: v @ A.T + 0.01, size=5).table)
    out = torch.empty(6, 8, 3)
    for seed in (8, 9):
        light = torch.rand(6, 8, 3, generator=torch.Generator().manual_seed(seed))
        assert table.apply(light, out=out) is out
        np.testing.assert_allclose(out.numpy(), light.numpy() @ A.T + 0.01, atol=1e-5)
        planar = light.permute(2, 0, 1).contiguous().permute(1, 2, 0)
        np.testing.assert_allclose(table.apply(planar).numpy(), light.numpy() @ A.T + 0.01, atol=1e-5)
    assert table._scratch.count() == 1
    colours = torch.rand(10, 3, generator=torch.Generator().manual_seed(10))  # a list of colours: (n, 3)
    np.testing.assert_allclose(table.apply(colours).numpy(), colours.numpy() @ A.T + 0.01, atol=1e-5)
    with pytest.raises(EdofprojError, match="NaN or infinite"):
        table.apply(torch.full((2, 2, 3), float("inf")))


def test_tables_keep_their_buffers_per_thread():
    """The live loop's device thread (a new target) and compute thread (each frame) apply the same
    table at once: each thread gets its own buffers, and both results are right."""
    table = ChannelInverseTable(np.random.default_rng(13).uniform(size=(3, 1000)))
    lights = [torch.rand(6, 8, 3, generator=torch.Generator().manual_seed(seed)) for seed in (11, 12)]
    expected = [table.table[np.arange(3), np.rint(light.numpy() * 999).astype(int)] for light in lights]
    seen = {}

    def other_thread():
        seen["result"] = table.apply(lights[1]).numpy()
        seen["buffers"] = table._scratch.get((6, 8, 3))

    thread = threading.Thread(target=other_thread)
    thread.start()
    thread.join()
    np.testing.assert_array_equal(table.apply(lights[0]).numpy(), expected[0])
    np.testing.assert_array_equal(seen["result"], expected[1])
    assert table._scratch.get((6, 8, 3))[0] is not seen["buffers"][0]
