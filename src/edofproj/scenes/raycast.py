"""One ray per projector pixel, cast into a scene with trimesh.

Pixel ``(v, u)`` (row, column) of an ``H x W`` image sends its light from the lens (the origin)
through the pixel's centre on a screen at depth ``z``,

    ((u + 0.5 - W/2) q(z),  (v + 0.5 - H/2) q(z),  z),     q(z) = z / (T W_panel),

(:class:`~edofproj.optics.geometry.ProjectorGeometry`), i.e. along the direction
``d = ((u + 0.5 - W/2) / (T W_panel), (v + 0.5 - H/2) / (T W_panel), 1)``. The first surface the
ray meets at ``p = t d`` gives

* the axial depth ``z = p_z = t`` (the depth whose PSF applies, see :mod:`edofproj.imaging.screens`);
* the distance ``|p|`` from the lens;
* the surface normal ``n`` (of the hit triangle, turned to face the projector) and the incidence
  angle ``theta = arccos(-n . d / |d|)``;
* the hit mask (False where the ray meets nothing: that light is lost).

trimesh picks its ray engine: Embree (``pip install embreex``, the ``scenes-fast`` extra) when
installed, else its pure-NumPy intersector (with an R-tree of the triangles).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import EdofprojError
from .scene import Scene


@dataclass
class SceneCast:
    """Per-pixel results of ray casting, each ``(H, W)`` (``normal_m``: ``(H, W, 3)``); NaN where missed."""

    depth_m: np.ndarray  # axial depth z, float32, NaN where nothing is hit
    distance_m: np.ndarray  # |p|, float64
    normal: np.ndarray  # unit normal facing the projector, float64 (H, W, 3)
    incidence_deg: np.ndarray  # angle between the normal and the ray back to the lens, float64
    hit: np.ndarray  # bool
    mesh_index: np.ndarray  # int, -1 where missed (which scene mesh; the background is len(meshes))
    seconds: float = 0.0
    engine: str = ""

    @property
    def hit_fraction(self) -> float:
        return float(self.hit.mean())

    def depth_range_m(self) -> tuple[float, float]:
        depth = self.depth_m[self.hit]
        return float(depth.min()), float(depth.max())


def pixel_ray_directions(height_px: int, width_px: int, geometry) -> np.ndarray:
    """Ray directions ``(H, W, 3)`` with ``d_z = 1`` through the pixel centres (module docstring)."""
    height_px, width_px = int(height_px), int(width_px)
    if height_px < 1 or width_px < 1:
        raise EdofprojError(f"image size {height_px}x{width_px} px must be at least 1x1")
    scale = 1.0 / geometry.throw_width_m
    u = (np.arange(width_px) + 0.5 - width_px / 2) * scale
    v = (np.arange(height_px) + 0.5 - height_px / 2) * scale
    directions = np.empty((height_px, width_px, 3))
    directions[..., 0] = u[None, :]
    directions[..., 1] = v[:, None]
    directions[..., 2] = 1.0
    return directions


RAY_ENGINES = ("auto", "embree", "numpy")


def ray_engine_name(engine: str = "auto") -> str:
    """The engine ``engine`` resolves to: ``embree`` when asked or (``auto``) when trimesh can use it, else ``numpy``."""
    if engine not in RAY_ENGINES:
        raise EdofprojError(f"ray engine '{engine}' is not one of {', '.join(RAY_ENGINES)}")
    if engine == "embree" and not trimesh.ray.has_embree:
        raise EdofprojError("the embree ray engine needs the embreex package (pip install 'edofproj[scenes-fast]')")
    if engine == "auto":
        return "embree" if trimesh.ray.has_embree else "numpy"
    return engine


def _intersector(mesh: trimesh.Trimesh, engine: str):
    if ray_engine_name(engine) == "embree":
        from trimesh.ray.ray_pyembree import RayMeshIntersector as EmbreeIntersector

        return EmbreeIntersector(mesh)
    from trimesh.ray.ray_triangle import RayMeshIntersector

    return RayMeshIntersector(mesh)


def _scene_mesh(scene: Scene, geometry, height_px: int, width_px: int) -> tuple[trimesh.Trimesh, np.ndarray]:
    """All meshes (and the background) as one mesh, and each face's mesh index."""
    from .builtin import fronto_parallel_plane

    parts = [m.mesh for m in scene.meshes]
    if scene.background_m is not None:
        panel = type(geometry)(
            geometry.aperture_diameter_m,
            geometry.focus_distance_m,
            geometry.throw_ratio,
            max(geometry.width_px, width_px),
            max(geometry.height_px, height_px),
        )
        parts.append(fronto_parallel_plane(scene.background_m, panel))
    if not parts:
        raise EdofprojError(f"scene '{scene.name}' has no meshes and no background")
    owner = np.concatenate([np.full(len(p.faces), i) for i, p in enumerate(parts)])
    vertices = np.concatenate([np.asarray(p.vertices, dtype=np.float64) for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    faces = np.concatenate([np.asarray(p.faces) + o for p, o in zip(parts, offsets)])
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False), owner


def cast_scene(
    scene: Scene, height_px: int, width_px: int, geometry, stride: int = 1, engine: str = "auto"
) -> SceneCast:
    """Cast the rays of an ``H x W`` image (every ``stride``-th row and column) into ``scene``.

    Raises when no ray meets the scene (it lies outside the view) or when a ray enters a solid
    (a mesh not marked ``open``) and meets the inside of its surface: the mesh is not watertight.
    ``engine``: ``auto``, ``embree`` or ``numpy`` (module docstring).
    """
    clock = time.perf_counter()
    directions = pixel_ray_directions(height_px, width_px, geometry)[::stride, ::stride]
    shape = directions.shape[:2]
    mesh, owner = _scene_mesh(scene, geometry, height_px, width_px)
    rays = directions.reshape(-1, 3)
    origins = np.zeros_like(rays)
    locations, ray_index, face_index = _intersector(mesh, engine).intersects_location(
        origins, rays, multiple_hits=False
    )

    count = rays.shape[0]
    depth = np.full(count, np.nan)
    distance = np.full(count, np.nan)
    normal = np.full((count, 3), np.nan)
    incidence = np.full(count, np.nan)
    index = np.full(count, -1)
    if len(ray_index):
        d = rays[ray_index]
        d_unit = d / np.linalg.norm(d, axis=1, keepdims=True)
        n = np.asarray(mesh.face_normals)[face_index]
        facing = np.einsum("ij,ij->i", n, d_unit)  # > 0: the ray meets the back of the face
        inside = facing > 0
        owners = owner[face_index]
        solids = np.array([not m.open for m in scene.meshes] + [False])  # the background plane is open
        bad = inside & solids[owners]
        if np.any(bad):
            which = scene.meshes[int(owners[bad][0])]
            detail = "not watertight" if not which.mesh.is_watertight else "inside out (faces wound inward)"
            raise EdofprojError(
                f"mesh '{which.name}' is {detail}: {int(bad.sum())} projector rays meet the inside of its surface; "
                "close it, or mark it 'open: true' in a scene file if it is a sheet or a wall"
            )
        n = np.where(inside[:, None], -n, n)
        depth[ray_index] = locations[:, 2]
        distance[ray_index] = np.linalg.norm(locations, axis=1)
        normal[ray_index] = n
        incidence[ray_index] = np.degrees(np.arccos(np.clip(-np.einsum("ij,ij->i", n, d_unit), -1.0, 1.0)))
        index[ray_index] = owners
    hit = ~np.isnan(depth)
    if not np.any(hit):
        raise EdofprojError(
            f"scene '{scene.name}' is outside the projector's view: none of the {count} pixel rays meets it "
            f"(its depths {scene.depth_span_m()[0] * 1e3:.0f}-{scene.depth_span_m()[1] * 1e3:.0f} mm; "
            "+z is the optical axis, +x right, +y down, metres)"
        )
    if np.any(depth[hit] <= 0):
        raise EdofprojError(f"scene '{scene.name}' reaches behind the projector's lens (z <= 0)")
    return SceneCast(
        depth_m=depth.reshape(shape).astype(np.float32),
        distance_m=distance.reshape(shape),
        normal=normal.reshape(*shape, 3),
        incidence_deg=incidence.reshape(shape),
        hit=hit.reshape(shape),
        mesh_index=index.reshape(shape),
        seconds=time.perf_counter() - clock,
        engine=ray_engine_name(engine),
    )
