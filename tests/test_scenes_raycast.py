"""Ray casting per projector pixel against closed forms, and mesh files of every format read back."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import trimesh

from edofproj.errors import EdofprojError
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.scenes import Scene, SceneMesh, cast_scene, load_scene
from edofproj.scenes.builtin import BUILTIN_SCENES, builtin_scene, quad, sphere_mesh

H, W = 24, 32
ENGINES = ["pinhole", "numpy"] + (["embree"] if trimesh.ray.has_embree else [])


@pytest.fixture
def small_projector():
    """A 32 x 24 pixel projector: the image is the whole panel."""
    return ProjectorGeometry(throw_ratio=1.5, width_px=W, height_px=H)


def ray_slopes(geometry):
    u = (np.arange(W) + 0.5 - W / 2) / geometry.throw_width_m
    v = (np.arange(H) + 0.5 - H / 2) / geometry.throw_width_m
    return np.meshgrid(u, v)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("tilt_deg", [0.0, 25.0, -40.0])
def test_plane_at_known_tilt(small_projector, engine, tilt_deg):
    """z = z0 + x tan(t) meets the ray (u z, v z, z) at z = z0 / (1 - u tan t); normal (sin t, 0, -cos t)."""
    z0, t = 0.5, math.radians(tilt_deg)
    big = 0.3  # covers the view at 0.5 m (0.33 x 0.25 m) and stays in front of the lens
    corners = [[x, y, z0 + x * math.tan(t)] for x, y in ((-big, -big), (big, -big), (big, big), (-big, big))]
    scene = Scene("plane", [SceneMesh("plane", quad(np.array(corners)), open=True)])
    cast = cast_scene(scene, H, W, small_projector, engine=engine)
    u, v = ray_slopes(small_projector)
    expected = z0 / (1 - u * math.tan(t))
    assert cast.hit.all()
    np.testing.assert_allclose(cast.depth_m, expected, rtol=2e-6)
    normal = np.array([math.sin(t), 0.0, -math.cos(t)])
    np.testing.assert_allclose(cast.normal, np.broadcast_to(normal, cast.normal.shape), atol=1e-9)
    d = np.stack([u, v, np.ones_like(u)], -1)
    cos_theta = -(d @ normal) / np.linalg.norm(d, axis=-1)
    np.testing.assert_allclose(np.cos(np.radians(cast.incidence_deg)), cos_theta, atol=1e-6)
    np.testing.assert_allclose(cast.distance_m, expected * np.linalg.norm(d, axis=-1), rtol=2e-6)


@pytest.mark.parametrize("engine", ENGINES)
def test_sphere_depth_and_normals(small_projector, engine):
    """A sphere (centre c, radius R): t = (d.c - sqrt((d.c)^2 - |d|^2 (|c|^2 - R^2))) / |d|^2, z = t, n = (t d - c) / R.

    The view at 0.45 m is 0.3 x 0.225 m, so the silhouette is inside the image; tolerance: the icosphere's facets."""
    geometry = small_projector
    centre, radius = np.array([0.01, -0.005, 0.45]), 0.08
    scene = Scene("ball", [SceneMesh("ball", sphere_mesh(radius, centre, subdivisions=4))])
    cast = cast_scene(scene, H, W, geometry, engine=engine)
    u, v = ray_slopes(geometry)
    d = np.stack([u, v, np.ones_like(u)], -1)
    dc = d @ centre
    dd = (d * d).sum(-1)
    disc = dc**2 - dd * (centre @ centre - radius**2)
    inside = disc > 0
    # pixels well inside the silhouette are hit, pixels well outside are not
    margin = 0.02 * dd * radius**2
    assert cast.hit[disc > margin].all() and not cast.hit[disc < -margin].any()
    assert 0.2 < cast.hit.mean() < 0.9
    t = (dc - np.sqrt(np.where(inside, disc, 0))) / dd
    sure = disc > 0.3 * dd * radius**2  # away from the grazing rim
    np.testing.assert_allclose(cast.depth_m[sure], t[sure], atol=radius * 2e-3)
    normal = (t[..., None] * d - centre) / radius
    angle = np.degrees(np.arccos(np.clip((cast.normal[sure] * normal[sure]).sum(-1), -1, 1)))
    assert angle.max() < 3.0  # facets of a subdivision-4 icosphere span about 2.4 degrees


@pytest.mark.slow
def test_engines_agree_on_a_built_in_scene():
    """The pinhole rasterizer and trimesh's own intersector see the same depths (sphere in front of a wall)."""
    geometry = ProjectorGeometry(width_px=W * 4, height_px=H * 4)
    scene = builtin_scene("sphere_wall", geometry)
    pinhole = cast_scene(scene, H * 4, W * 4, geometry, stride=2, engine="pinhole")
    reference = cast_scene(scene, H * 4, W * 4, geometry, stride=2, engine="numpy")
    assert (pinhole.hit == reference.hit).all()
    np.testing.assert_allclose(pinhole.depth_m, reference.depth_m, rtol=1e-6)
    assert (pinhole.mesh_index == reference.mesh_index).mean() > 0.99


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb"])
def test_mesh_formats_read_back_to_the_same_depth_map(tmp_path, small_projector, suffix):
    ball = sphere_mesh(0.05, (0.0, 0.0, 0.4), subdivisions=3)
    block = trimesh.creation.box(bounds=[[-0.2, -0.2, 0.55], [0.2, 0.2, 0.6]])
    mesh = trimesh.util.concatenate([ball, block])
    path = tmp_path / f"scene{suffix}"
    mesh.export(path)
    reference = cast_scene(Scene("ref", [SceneMesh("ref", mesh)]), H, W, small_projector)
    loaded = load_scene(path, small_projector)
    cast = cast_scene(loaded, H, W, small_projector)
    np.testing.assert_array_equal(cast.hit, reference.hit)
    np.testing.assert_allclose(cast.depth_m, reference.depth_m, rtol=1e-6)
    assert np.isnan(cast.depth_m[~cast.hit]).all()


def test_scene_file_poses_meshes(tmp_path, small_projector):
    """A unit cube scaled to 0.1 m, turned 45 degrees about y and placed at 0.5 m: its front edge is the
    vertical line at z_e = 0.5 - 0.05 sqrt(2) on the axis, its faces z = z_e + |x|; the nearest pixel
    centres (u = +-0.5 px / (T W)) see z = z_e / (1 - |u|)."""
    trimesh.creation.box(extents=[1, 1, 1]).export(tmp_path / "cube.stl")
    (tmp_path / "scene.yaml").write_text(
        "meshes:\n  - file: cube.stl\n    scale: 0.1\n    rotation_deg: [0, 45, 0]\n    position_m: [0, 0, 0.5]\n"
        "background_m: 0.7\n"
    )
    cast = cast_scene(load_scene(tmp_path / "scene.yaml"), H, W, small_projector)
    assert cast.hit.all()
    edge = 0.5 - 0.05 * math.sqrt(2)
    assert cast.depth_m.min() == pytest.approx(edge / (1 - 0.5 / small_projector.throw_width_m), rel=1e-5)
    assert cast.depth_m.max() == pytest.approx(0.7, rel=1e-6)  # the background around the cube
    assert cast.incidence_deg[cast.mesh_index == 0].min() == pytest.approx(45, abs=3)


@pytest.mark.slow
def test_builtin_scenes_span_their_stated_depths():
    geometry = ProjectorGeometry()
    stated = {
        "box_corner": (525, 700),
        "sphere": (400, 480),
        "cylinder": (400, 490),
        "steps": (350, 650),
        "sphere_wall": (340, 750),
    }
    assert set(stated) == set(BUILTIN_SCENES)
    for name, (near, far) in stated.items():
        cast = cast_scene(builtin_scene(name, geometry), 600, 800, geometry, stride=2)
        lo, hi = cast.depth_range_m()
        assert lo * 1e3 == pytest.approx(near, abs=6), name
        assert hi * 1e3 == pytest.approx(far, abs=12), name


def screen_corners(depth_m: float, facing_projector: bool) -> np.ndarray:
    """A 0.6 m square screen at ``depth_m``; wound so that its normal points at the projector (-z) or away."""
    corners = np.array([[-0.3, -0.3, depth_m], [0.3, -0.3, depth_m], [0.3, 0.3, depth_m], [-0.3, 0.3, depth_m]])
    return corners[::-1] if facing_projector else corners


@pytest.mark.parametrize("facing_projector", [True, False])
def test_a_bare_single_sheet_is_a_screen_whichever_way_it_faces(tmp_path, small_projector, facing_projector):
    """A mesh file holding one rectangle (two triangles) is a screen: its depth is the plane's, facing the
    projector or not; wound away, a warning says which way it faces (issue 29)."""
    sheet = quad(screen_corners(0.5, facing_projector))
    assert (sheet.face_normals[:, 2] < 0).all() == facing_projector  # -z: toward the projector
    path = tmp_path / "screen.obj"
    sheet.export(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cast = cast_scene(load_scene(path, small_projector), H, W, small_projector)
    assert cast.hit.all() and np.allclose(cast.depth_m, 0.5, atol=1e-6)
    assert np.allclose(cast.normal[..., 2], -1.0)  # the normal seen is the side facing the projector
    messages = [str(w.message) for w in caught]
    if facing_projector:
        assert messages == []
    else:
        assert len(messages) == 1 and "screen.obj" in messages[0] and "away from the projector" in messages[0]


def test_a_bare_mesh_seen_from_both_sides_of_its_faces_is_still_refused(tmp_path, small_projector):
    """A solid with a hole: some rays meet the outside, some the inside through the hole."""
    holed = sphere_mesh(0.1, (0.0, 0.0, 0.5), subdivisions=2)
    holed.update_faces(holed.face_normals[:, 2] > -0.7)  # a cap facing the projector removed
    path = tmp_path / "holed.obj"
    holed.export(path)
    with pytest.raises(EdofprojError, match=r"holed\.obj' is not watertight: .* meet the inside"):
        cast_scene(load_scene(path, small_projector), H, W, small_projector)
