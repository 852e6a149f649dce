"""Built-in scenes made from primitives (``trimesh.creation``), so nothing has to be downloaded.

Each is placed for the projector's view (``geometry``: throw ratio ``T`` and panel size
``W x H``; the view at depth ``z`` is ``z / T`` wide and ``z H / (T W)`` tall). The depths seen
by the default projector (800 x 600 pixels, ``T = 1.5``) at full panel size:

==================  ============================================================  ==========
name                what                                                          seen (mm)
==================  ============================================================  ==========
``box_corner``      two walls at 90 degrees (inside of a box's corner), the       525-700
                    corner line vertical on the axis at 700 mm
``sphere``          a sphere of radius 100 mm centred on the axis at 500 mm        400-480
``cylinder``        a vertical cylinder of radius 120 mm, axis at 520 mm           400-490
``steps``           four fronto-parallel steps, a quarter of the width each,       350-650
                    350 / 450 / 550 / 650 mm from left to right
``sphere_wall``     a sphere of radius 80 mm at 420 mm in front of a wall at       340-750
                    750 mm: a depth edge all around the sphere
==================  ============================================================  ==========

Light outside an object (around the sphere and the cylinder) is lost. Images smaller than the
panel see the centre of the view.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..errors import EdofprojError
from ..optics.geometry import ProjectorGeometry
from .scene import Scene, SceneMesh


def _geometry(geometry):
    if geometry is None:
        return ProjectorGeometry()
    return geometry


def _half_view_m(geometry, depth_m: float, margin: float = 1.5) -> tuple[float, float]:
    """Half the view's width and height at ``depth_m`` times ``margin``."""
    half_width = depth_m * geometry.width_px / (2 * geometry.throw_width_m)
    half_height = depth_m * geometry.height_px / (2 * geometry.throw_width_m)
    return margin * half_width, margin * half_height


def quad(corners: np.ndarray) -> trimesh.Trimesh:
    """An open rectangle from four corners ``(4, 3)`` in order around it (two triangles)."""
    return trimesh.Trimesh(vertices=np.asarray(corners, dtype=float), faces=[[0, 1, 2], [0, 2, 3]], process=False)


def fronto_parallel_plane(depth_m: float, geometry=None, margin: float = 1.5) -> trimesh.Trimesh:
    """A plane ``z = depth_m`` covering the projector's view (times ``margin``)."""
    geometry = _geometry(geometry)
    hx, hy = _half_view_m(geometry, depth_m, margin)
    return quad(np.array([[-hx, -hy, depth_m], [hx, -hy, depth_m], [hx, hy, depth_m], [-hx, hy, depth_m]]))


def sphere_mesh(radius_m: float, centre_m, subdivisions: int = 5) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_m)
    mesh.apply_translation(np.asarray(centre_m, dtype=float))
    return mesh


def box_corner(geometry=None) -> Scene:
    geometry = _geometry(geometry)
    corner_m = 0.70
    _, hy = _half_view_m(geometry, corner_m)
    reach = corner_m  # walls run from the corner line to z = 0 (far beyond the view's edges)
    walls = []
    for side in (-1.0, 1.0):
        # the wall z = corner - |x| on one side of the axis
        x_far, x_near = 0.0, side * reach * 0.9
        z_far, z_near = corner_m, corner_m - abs(x_near)
        walls.append(
            quad(np.array([[x_far, -hy, z_far], [x_near, -hy, z_near], [x_near, hy, z_near], [x_far, hy, z_far]]))
        )
    meshes = [SceneMesh("left wall", walls[0], True), SceneMesh("right wall", walls[1], True)]
    return Scene("box_corner", meshes, None, "inside of a box's corner: two walls at 90 deg, corner at 700 mm")


def sphere(geometry=None) -> Scene:
    return Scene(
        "sphere",
        [SceneMesh("sphere", sphere_mesh(0.10, (0.0, 0.0, 0.50)))],
        None,
        "sphere of radius 100 mm centred on the axis at 500 mm",
    )


def cylinder(geometry=None) -> Scene:
    geometry = _geometry(geometry)
    axis_m, radius_m = 0.52, 0.12
    _, hy = _half_view_m(geometry, axis_m, margin=2.0)
    mesh = trimesh.creation.cylinder(radius=radius_m, height=2 * hy, sections=128)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))  # axis along y
    mesh.apply_translation([0.0, 0.0, axis_m])
    return Scene("cylinder", [SceneMesh("cylinder", mesh)], None, "vertical cylinder, radius 120 mm, axis at 520 mm")


def steps(geometry=None) -> Scene:
    """Four slabs: slab ``i`` at depth ``z_i`` ends at the ray of column ``(i + 1) W / 4``; nearer slabs
    occlude the farther ones' left parts, so each step is exactly a quarter of the image wide."""
    geometry = _geometry(geometry)
    depths_m = (0.35, 0.45, 0.55, 0.65)
    edge_slope = geometry.width_px / (2 * geometry.throw_width_m)  # x / z of the image's right edge
    meshes = []
    for index, depth in enumerate(depths_m):
        hx, hy = _half_view_m(geometry, depth)
        right = (-edge_slope + (index + 1) * edge_slope / 2) * depth if index < len(depths_m) - 1 else hx
        slab = trimesh.creation.box(bounds=[[-hx, -hy, depth], [right, hy, depth + 0.02]])
        meshes.append(SceneMesh(f"step {depth * 1e3:.0f} mm", slab))
    return Scene("steps", meshes, None, "four steps at 350, 450, 550, 650 mm, left to right")


def sphere_wall(geometry=None) -> Scene:
    return Scene(
        "sphere_wall",
        [SceneMesh("sphere", sphere_mesh(0.08, (0.0, 0.0, 0.42)))],
        0.75,
        "sphere of radius 80 mm at 420 mm in front of a wall at 750 mm",
    )


BUILTIN_SCENES = {
    "box_corner": box_corner,
    "sphere": sphere,
    "cylinder": cylinder,
    "steps": steps,
    "sphere_wall": sphere_wall,
}


def builtin_scene(name: str, geometry=None) -> Scene:
    """The built-in scene ``name`` for the projector ``geometry`` (default: the default projector)."""
    if name not in BUILTIN_SCENES:
        raise EdofprojError(f"unknown built-in scene '{name}' (known: {', '.join(BUILTIN_SCENES)})")
    return BUILTIN_SCENES[name](geometry)
