"""Tilted-plane depth maps against an explicit 3-D ray/plane intersection."""

import math

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.imaging.screens import tilted_plane_depth_map, tilted_plane_far_m, tilted_plane_tilt_deg


def ray_plane_depths(width, tilt_deg, z0, throw_width):
    """Axial depth where each column's ray meets the plane through (0, 0, z0) with normal rotated by tilt about y."""
    normal = np.array([-math.sin(math.radians(tilt_deg)), 0.0, math.cos(math.radians(tilt_deg))])
    point = np.array([0.0, 0.0, z0])
    depths = []
    for c in range(width):
        direction = np.array([(c - (width - 1) / 2) / throw_width, 0.0, 1.0])
        t = normal @ point / (normal @ direction)
        depths.append((t * direction)[2])
    return np.array(depths)


def test_map_matches_the_ray_plane_intersection(geometry):
    width, tilt = 320, 35.0
    truth = ray_plane_depths(width, tilt, 0.6, geometry.throw_width_m)
    depth = tilted_plane_depth_map(4, width, tilt, truth[0], truth[-1])
    np.testing.assert_allclose(depth, np.broadcast_to(truth, (4, width)), rtol=1e-12)
    # the tilt recovered from the two edge depths is the plane's tilt
    assert tilted_plane_tilt_deg(truth[0], truth[-1], width, geometry) == pytest.approx(tilt, abs=1e-9)
    assert tilted_plane_far_m(truth[0], tilt, width, geometry) == pytest.approx(truth[-1], rel=1e-12)


def test_negative_tilt_mirrors_the_map():
    a = tilted_plane_depth_map(3, 50, 20.0, 0.4, 0.7)
    b = tilted_plane_depth_map(3, 50, -20.0, 0.4, 0.7)
    np.testing.assert_array_equal(a, b[:, ::-1])
    assert a[0, 0] == pytest.approx(0.4) and a[0, -1] == pytest.approx(0.7)
    assert np.all(np.diff(a[0]) > 0)


def test_fronto_parallel_and_invalid_geometry(geometry):
    np.testing.assert_array_equal(tilted_plane_depth_map(2, 3, 0.0, 0.5, 0.5), np.full((2, 3), 0.5))
    with pytest.raises(EdofprojError, match="must equal far"):
        tilted_plane_depth_map(2, 3, 0.0, 0.5, 0.6)
    with pytest.raises(EdofprojError, match="needs near < far"):
        tilted_plane_depth_map(2, 3, 10.0, 0.6, 0.5)
    with pytest.raises(EdofprojError, match="between -90 and 90"):
        tilted_plane_depth_map(2, 3, 90.0, 0.5, 0.6)
    with pytest.raises(EdofprojError, match="positive depth"):
        tilted_plane_depth_map(2, 3, 10.0, -0.5, 0.6)
    # with throw ratio 1.5 the edge ray of an 800 px image is 18.4 deg off axis: 72 deg is the limit
    with pytest.raises(EdofprojError, match="at most 71.6 deg"):
        tilted_plane_far_m(0.6, 75.0, 800, geometry)
