"""Reading scenes: a built-in name, a YAML scene file or a mesh file (the format is in :mod:`.scene`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
import yaml

from ..config import safe_load_yaml
from ..errors import EdofprojError
from .builtin import BUILTIN_SCENES, builtin_scene
from .scene import Scene, SceneMesh

#: Mesh files trimesh reads for a scene.
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".glb")
SCENE_EXTENSIONS = (".yaml", ".yml")
SCENE_KEYS = {"meshes", "background_m"}
MESH_KEYS = {"file", "scale", "rotation_deg", "position_m", "open"}


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """A triangle mesh from an OBJ, PLY, STL or GLB file (a GLB's nodes are flattened with their transforms)."""
    path = Path(path)
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise EdofprojError(f"mesh '{path}' has an unsupported extension (supported: {', '.join(MESH_EXTENSIONS)})")
    if not path.is_file():
        raise EdofprojError(f"mesh file '{path}' does not exist")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for damaged files
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise EdofprojError(f"cannot read mesh '{path}': {message}") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise EdofprojError(f"mesh '{path}' holds no triangles")
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise EdofprojError(f"mesh '{path}' has non-finite vertex coordinates")
    return trimesh.Trimesh(vertices=vertices, faces=np.asarray(loaded.faces), process=False)


def _vector(value, key: str, where: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise EdofprojError(f"{where}: '{key}' must be three finite numbers, got {value!r}")
    return array


def pose_matrix(rotation_deg=(0.0, 0.0, 0.0), position_m=(0.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """``4x4`` transform ``p -> T + Rz Ry Rx (s p)`` (rotations about x, then y, then z; degrees)."""
    rx, ry, rz = np.radians(np.asarray(rotation_deg, dtype=float))
    matrix = trimesh.transformations.euler_matrix(rx, ry, rz, axes="sxyz")
    matrix[:3, :3] *= float(scale)
    matrix[:3, 3] = np.asarray(position_m, dtype=float)
    return matrix


def _refuse_unknown_keys(mapping: dict, known, what: str) -> None:
    """A one-line error naming the keys of ``mapping`` outside ``known`` (and the known ones), if any."""
    unknown = set(mapping) - set(known)
    if unknown:
        raise EdofprojError(
            f"{what} has unknown key(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(known))})"
        )


def _posed_mesh(entry, index: int, base: Path, where: str) -> SceneMesh:
    if not isinstance(entry, dict):
        raise EdofprojError(f"{where}: meshes[{index}] must be a mapping with at least 'file'")
    _refuse_unknown_keys(entry, MESH_KEYS, f"{where}: meshes[{index}]")
    if "file" not in entry:
        raise EdofprojError(f"{where}: meshes[{index}] needs 'file'")
    scale = entry.get("scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (np.isfinite(scale) and scale > 0):
        raise EdofprojError(f"{where}: meshes[{index}].scale must be a positive number, got {scale!r}")
    is_open = entry.get("open", False)
    if not isinstance(is_open, bool):
        raise EdofprojError(f"{where}: meshes[{index}].open must be true or false, got {is_open!r}")
    rotation = _vector(entry.get("rotation_deg", [0, 0, 0]), "rotation_deg", f"{where}: meshes[{index}]")
    position = _vector(entry.get("position_m", [0, 0, 0]), "position_m", f"{where}: meshes[{index}]")
    path = _confined_mesh_path(str(entry["file"]), base, f"{where}: meshes[{index}].file")
    mesh = read_mesh(path)
    mesh.apply_transform(pose_matrix(rotation, position, float(scale)))
    return SceneMesh(path.name, mesh, is_open)


def _confined_mesh_path(name: str, base: Path, where: str) -> Path:
    """``base / name`` for a relative ``name`` that stays inside the scene file's folder ``base``
    (subfolders allowed; absolute paths and ``..`` refused): a scene names its own files only."""
    relative = Path(name)
    if not name or relative.is_absolute() or ".." in relative.parts:
        raise EdofprojError(
            f"{where} '{name}' must be a path relative to the scene file's folder, inside it (no absolute path, no '..')"
        )
    return base / relative


def read_scene_file(path: str | Path) -> Scene:
    """A YAML scene file (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise EdofprojError(f"scene file '{path}' does not exist")
    try:
        data = safe_load_yaml(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise EdofprojError(f"cannot read scene file '{path}': {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise EdofprojError(f"scene file '{path}' must be a mapping with 'meshes' (and optionally 'background_m')")
    _refuse_unknown_keys(data, SCENE_KEYS, f"scene file '{path}'")
    entries = data.get("meshes") or []
    if not isinstance(entries, list):
        raise EdofprojError(f"scene file '{path}': 'meshes' must be a list")
    background = data.get("background_m")
    if background is not None and (
        isinstance(background, bool) or not isinstance(background, (int, float)) or not (0 < background < np.inf)
    ):
        raise EdofprojError(f"scene file '{path}': background_m must be a positive depth in metres, got {background!r}")
    if not entries and background is None:
        raise EdofprojError(f"scene file '{path}' has no meshes and no background: nothing to project onto")
    meshes = [_posed_mesh(entry, i, path.parent, f"scene file '{path}'") for i, entry in enumerate(entries)]
    return Scene(path.stem, meshes, None if background is None else float(background))


def load_scene(spec: str | Path, geometry=None) -> Scene:
    """A built-in scene name, a YAML scene file or a mesh file (module docstring).

    ``geometry`` (:class:`~edofproj.optics.geometry.ProjectorGeometry`) sizes the built-in
    scenes to the projector's view; it defaults to the default projector.
    """
    text = str(spec)
    if text in BUILTIN_SCENES:
        return builtin_scene(text, geometry)
    path = Path(text)
    suffix = path.suffix.lower()
    if suffix in SCENE_EXTENSIONS:
        return read_scene_file(path)
    if suffix in MESH_EXTENSIONS:
        return Scene(path.stem, [SceneMesh(path.name, read_mesh(path), False, bare=True)])
    raise EdofprojError(
        f"scene '{text}' is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) nor a scene file "
        f"({', '.join(SCENE_EXTENSIONS)}) or mesh file ({', '.join(MESH_EXTENSIONS)})"
    )
