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

Ray engines (``engine``):

* ``pinhole`` -- every ray starts at the lens, so casting them is exact perspective
  rasterization: each triangle is projected onto the image, the Moller-Trumbore test
  (``t = e2 . ((o - p0) x e1) / (e1 . (d x e2))`` with barycentric bounds) runs for the pixel
  centres inside its projected bounding box only, and the nearest ``t`` per pixel wins
  (vectorized NumPy, in chunks of at most :data:`PINHOLE_CHUNK` ray-triangle pairs); needs every
  vertex in front of the lens (``z > 0``);
* ``embree`` -- trimesh with Embree (``pip install embreex``, the ``scenes-fast`` extra; float32);
* ``numpy`` -- trimesh's own intersector (an R-tree query per ray: about a minute for 600 x 800
  rays, kept as an independent reference);
* ``auto`` -- ``embree`` when installed, else ``pinhole`` when every vertex is in front of the
  lens, else ``numpy``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from ..errors import EdofprojError
from .builtin import fronto_parallel_plane
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


RAY_ENGINES = ("auto", "pinhole", "embree", "numpy")
#: Largest number of ray-triangle pairs the pinhole engine tests at once (memory: ~40 bytes x 30 each).
PINHOLE_CHUNK = 2_000_000
#: Vertices closer to the lens plane than this (m) cannot be projected by the pinhole engine.
MIN_PINHOLE_DEPTH_M = 1e-6


def ray_engine_name(engine: str = "auto", mesh: trimesh.Trimesh | None = None) -> str:
    """The engine ``engine`` resolves to for ``mesh`` (module docstring)."""
    if engine not in RAY_ENGINES:
        raise EdofprojError(f"ray engine '{engine}' is not one of {', '.join(RAY_ENGINES)}")
    if engine == "embree" and not trimesh.ray.has_embree:
        raise EdofprojError("the embree ray engine needs the embreex package (pip install 'edofproj[scenes-fast]')")
    in_front = mesh is None or float(np.asarray(mesh.vertices)[:, 2].min()) > MIN_PINHOLE_DEPTH_M
    if engine == "pinhole" and not in_front:
        raise EdofprojError("the pinhole ray engine needs every vertex in front of the lens (z > 0)")
    if engine == "auto":
        if trimesh.ray.has_embree:
            return "embree"
        return "pinhole" if in_front else "numpy"
    return engine


def pinhole_first_hits(
    mesh: trimesh.Trimesh, columns_px: np.ndarray, rows_px: np.ndarray, scale: float, width_px: int, height_px: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of the rays through pixel centres ``columns_px x rows_px`` (``d = ((u + 0.5 - W/2) s,
    (v + 0.5 - H/2) s, 1)``): ``(ray index into the rows x columns grid, t = z, face index)``."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = vertices[np.asarray(mesh.faces)]  # (F, 3, 3)
    # projected pixel coordinates of the corners: u + 0.5 - W/2 = x / (z s)
    col = triangles[..., 0] / (triangles[..., 2] * scale) + width_px / 2 - 0.5
    row = triangles[..., 1] / (triangles[..., 2] * scale) + height_px / 2 - 0.5
    # candidate index ranges in the (strided) grid
    j0 = np.searchsorted(columns_px, col.min(1), side="left")
    j1 = np.searchsorted(columns_px, col.max(1), side="right")
    i0 = np.searchsorted(rows_px, row.min(1), side="left")
    i1 = np.searchsorted(rows_px, row.max(1), side="right")
    nx, ny = np.maximum(j1 - j0, 0), np.maximum(i1 - i0, 0)
    counts = nx * ny
    n_cols = columns_px.size
    best_t = np.full(rows_px.size * n_cols, np.inf)
    best_face = np.full(rows_px.size * n_cols, -1)
    faces = np.flatnonzero(counts)
    start = 0
    while start < faces.size:
        stop = start + max(1, int(np.searchsorted(np.cumsum(counts[faces[start:]]), PINHOLE_CHUNK, side="right")))
        chosen = faces[start:stop]
        start = stop
        repeat = counts[chosen]
        face = np.repeat(chosen, repeat)
        offset = np.arange(repeat.sum()) - np.repeat(np.cumsum(repeat) - repeat, repeat)
        i = i0[face] + offset // nx[face]
        j = j0[face] + offset % nx[face]
        d = np.stack(
            [(columns_px[j] + 0.5 - width_px / 2) * scale, (rows_px[i] + 0.5 - height_px / 2) * scale, np.ones(j.size)],
            axis=1,
        )
        p0 = triangles[face, 0]
        e1 = triangles[face, 1] - p0
        e2 = triangles[face, 2] - p0
        pvec = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pvec)
        ok = np.abs(det) > 1e-18
        inverse = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = -p0
        u = np.einsum("ij,ij->i", tvec, pvec) * inverse
        qvec = np.cross(tvec, e1)
        v = np.einsum("ij,ij->i", d, qvec) * inverse
        t = np.einsum("ij,ij->i", e2, qvec) * inverse
        eps = 1e-12
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 0)
        pixel = (i * n_cols + j)[hit]
        t, face = t[hit], face[hit]
        order = np.lexsort((t, pixel))
        pixel, t, face = pixel[order], t[order], face[order]
        first = np.ones(pixel.size, dtype=bool)
        first[1:] = pixel[1:] != pixel[:-1]
        pixel, t, face = pixel[first], t[first], face[first]
        closer = t < best_t[pixel]
        best_t[pixel[closer]] = t[closer]
        best_face[pixel[closer]] = face[closer]
    rays = np.flatnonzero(best_face >= 0)
    return rays, best_t[rays], best_face[rays]


def _intersector(mesh: trimesh.Trimesh, engine: str):
    if ray_engine_name(engine) == "embree":
        # optional: the scenes-fast extra (embreex)
        from trimesh.ray.ray_pyembree import RayMeshIntersector as EmbreeIntersector

        return EmbreeIntersector(mesh)

    return RayMeshIntersector(mesh)


def _scene_mesh(scene: Scene, geometry, height_px: int, width_px: int) -> tuple[trimesh.Trimesh, np.ndarray]:
    """All meshes (and the background) as one mesh, and each face's mesh index."""
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
    engine = ray_engine_name(engine, mesh)
    if engine == "pinhole":
        columns = np.arange(0, int(width_px), stride, dtype=np.float64)
        rows = np.arange(0, int(height_px), stride, dtype=np.float64)
        ray_index, t, face_index = pinhole_first_hits(
            mesh, columns, rows, 1.0 / geometry.throw_width_m, int(width_px), int(height_px)
        )
        locations = rays[ray_index] * t[:, None]
    else:
        locations, ray_index, face_index = _intersector(mesh, engine).intersects_location(
            np.zeros_like(rays), rays, multiple_hits=False
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
        for k in np.unique(owners[bad]).tolist():
            which = scene.meshes[k]
            if which.bare and not which.mesh.is_watertight and np.all(inside[owners == k]):
                warnings.warn(
                    f"mesh '{which.name}' is an open sheet whose faces point away from the projector (all "
                    f"{int(np.sum(owners == k))} rays that meet it meet their backs): lit as a two-sided screen; "
                    "reverse its faces' winding, or mark it 'open: true' in a scene file, to silence this",
                    stacklevel=2,
                )
                bad &= owners != k
        if np.any(bad):
            k = int(owners[bad][0])
            which = scene.meshes[k]
            detail = "not watertight" if not which.mesh.is_watertight else "inside out (faces wound inward)"
            front = int(np.sum((owners == k) & ~inside))
            raise EdofprojError(
                f"mesh '{which.name}' is {detail}: {int(bad.sum())} projector rays meet the inside of its surface "
                f"(the back of its faces) and {front} its outside; close it, or mark it 'open: true' in a scene file "
                "if it is a sheet or a wall"
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
        engine=engine,
    )
