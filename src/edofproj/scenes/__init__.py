"""Projection mapping onto 3-D objects: scenes made of meshes, seen from the projector.

* :mod:`.scene` -- a scene (meshes with poses, an optional background plane) and its file format;
* :mod:`.loader` -- reading one: a built-in name, a YAML scene file, or a single mesh file
  (OBJ, PLY, STL, GLB);
* :mod:`.builtin` -- scenes made from primitives (box corner, sphere, cylinder, steps,
  sphere in front of a wall);
* :mod:`.raycast` -- one ray per projector pixel: axial depth, normal, incidence angle, hit mask;
* :mod:`.render` -- the projection onto the scene through the depth-layer renderer;
* :mod:`.random_screens` -- random depth-varying screens (tilts, steps, smooth relief) for training.

Frame (OpenCV's camera frame): origin at the projector lens, +z along the optical axis, +x
toward the image's right edge, +y toward its bottom edge; metres.
"""

from .builtin import BUILTIN_SCENES, builtin_scene  # noqa: F401
from .loader import MESH_EXTENSIONS, load_scene, read_mesh  # noqa: F401
from .raycast import SceneCast, cast_scene, pixel_ray_directions  # noqa: F401
from .render import check_scene_depth_range, relative_irradiance, render_scene  # noqa: F401
from .scene import Scene, SceneMesh  # noqa: F401
