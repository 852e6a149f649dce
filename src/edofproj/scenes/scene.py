"""A scene: meshes with poses in the projector's frame (read by :mod:`.loader`).

A scene is one or more triangle meshes in metres in the projector's frame (origin at the lens,
+z along the optical axis, +x toward the image's right edge, +y toward its bottom edge) and an
optional fronto-parallel background plane at ``background_m``. It comes from

* a built-in name (:data:`~edofproj.scenes.builtin.BUILTIN_SCENES`), nothing to download;
* a single mesh file (``.obj``, ``.ply``, ``.stl``, ``.glb``), taken as it is (metres,
  projector frame);
* a YAML scene file::

      meshes:
        - file: bust.stl              # relative to the YAML file
          scale: 0.001                # file units -> metres (default 1)
          rotation_deg: [0, 30, 0]    # about x, then y, then z (default none)
          position_m: [0, 0, 0.55]    # translation after rotation (default 0)
          open: false                 # an open surface (a wall, a sheet): seen from both sides
      background_m: 0.75              # optional fronto-parallel plane at this depth

A mesh that is not ``open`` is a solid: the projector must see its outside. When a ray enters
a solid through a hole and hits the inside of its surface, the mesh is reported as not
watertight (:func:`~edofproj.scenes.raycast.cast_scene`); open surfaces are lit from either side.

A single mesh file says nothing about being a solid or a sheet (``bare``). When it is not
watertight and every ray that meets it meets the back of its faces, it is a sheet wound away from
the projector (a screen whose normals point away): it is lit as an open surface, with a warning
that says which way it faces. When some rays meet the front of its faces and others the back, it
is a solid with a hole, and it is refused as not watertight like any solid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import trimesh


@dataclass
class SceneMesh:
    """One posed mesh: ``mesh`` (trimesh, metres, projector frame), a display ``name``, ``open``;
    ``bare``: read from a mesh file alone, nothing saying whether it is a solid or a sheet."""

    name: str
    mesh: trimesh.Trimesh
    open: bool = False
    bare: bool = False


@dataclass
class Scene:
    """Meshes in the projector's frame plus an optional background plane depth (m)."""

    name: str
    meshes: list[SceneMesh] = field(default_factory=list)
    background_m: float | None = None
    description: str = ""

    def depth_span_m(self) -> tuple[float, float]:
        """The smallest and largest ``z`` of the meshes' vertices and the background (not only what is seen)."""
        zs = [float(m.mesh.vertices[:, 2].min()) for m in self.meshes] + [
            float(m.mesh.vertices[:, 2].max()) for m in self.meshes
        ]
        if self.background_m is not None:
            zs.append(self.background_m)
        return min(zs), max(zs)
