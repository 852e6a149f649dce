"""Surface textures: the built-in set for evaluation and the random surfaces drawn in training.

A texture ``T`` in ``[0, 1]`` becomes a reflectance (:mod:`edofproj.imaging.surfaces`) as

    s = tint ⊙ (floor + (1 - floor) T),

so the darkest point still reflects ``floor`` (a real paint or print rarely reflects less than a
few per cent).

Built-in textures (:data:`BUILTIN_TEXTURES`, ``edofproj evaluate --surface NAME``; ``floor`` =
:data:`BUILTIN_FLOOR`, no tint), each at any size (photographs scaled to cover it and centre-cropped):

* procedural, from a fixed seed (:data:`TEXTURE_SEED`) that training never uses: ``leaves``
  (textured dead leaves of natural colours), ``field`` (a smooth power-law colour field),
  ``checker`` (a two-colour checkerboard of 16 px squares: sharp edges everywhere);
* photographs shipped with scikit-image: ``brick`` and ``gravel`` (grey), never drawn as training
  surfaces (:data:`HELD_OUT_PHOTOS`);
* ``white``: the white screen (``s = 1``), today's evaluation.

Training surfaces (:class:`TrainingSurfaces`, ``net.surface_input: true``): per sample, with
probability :data:`WHITE_PROBABILITY` the white screen, else a texture -- procedural (textured dead
leaves or a smooth field) or a crop of a built-in photograph other than the held-out ones, with
probability 1/2 each -- with ``floor ~ U(0.02, 0.3)`` and ``tint_c ~ U(0.6, 1)``; the ambient
illuminance ``E_c = e (1 + 0.2 u_c)``, ``e ~ U(0, 0.15)``, ``u_c ~ U(-1, 1)``, is reflected by the
surface: ``a = s ⊙ E``.
"""

from __future__ import annotations

import os
from typing import Callable

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import to_unit_float
from ..imaging.surfaces import read_reflectance
from .dead_leaves import natural_color_palette
from .photos import BUILTIN_PHOTOS, load_builtin_photo, random_crop
from .procedural import smooth_field_image, textured_dead_leaves_image
from .test_images import fit_to_size

#: Seed of the built-in procedural textures (training draws its surfaces from step-keyed generators).
TEXTURE_SEED = 20261125
#: Darkest reflectance of the built-in textures.
BUILTIN_FLOOR = 0.1
#: Photographs kept out of the training surfaces: the built-in photographic textures.
HELD_OUT_PHOTOS = ("brick", "gravel")
#: Probability of a white screen among the training surfaces.
WHITE_PROBABILITY = 0.1
FLOOR_RANGE = (0.02, 0.3)
TINT_RANGE = (0.6, 1.0)
AMBIENT_RANGE = (0.0, 0.15)
AMBIENT_TINT = 0.2
CHECKER_PX = 16


def reflectance_from_texture(texture: torch.Tensor, floor: float, tint=None) -> torch.Tensor:
    """``tint ⊙ (floor + (1 - floor) T)`` for a texture ``(..., 3, H, W)`` in ``[0, 1]``."""
    if not 0.0 <= floor <= 1.0:
        raise EdofprojError(f"the reflectance floor {floor:g} must lie in [0, 1]")
    rho = floor + (1.0 - floor) * texture.clamp(0.0, 1.0)
    if tint is not None:
        rho = rho * torch.as_tensor(tint, dtype=rho.dtype).reshape(3, 1, 1)
    return rho


def _generator(name: str) -> torch.Generator:
    return torch.Generator().manual_seed(TEXTURE_SEED + sum(name.encode()))


def _leaves(height: int, width: int) -> torch.Tensor:
    radius = max(min(height, width) / 64.0, 1.0)
    palette = natural_color_palette()
    return textured_dead_leaves_image(height, width, radius, 16 * radius, palette, _generator("leaves"))


def _field(height: int, width: int) -> torch.Tensor:
    return smooth_field_image(height, width, natural_color_palette(), _generator("field"), contrast_range=(0.25, 0.3))


def _checker(height: int, width: int) -> torch.Tensor:
    rows = (torch.arange(height) // CHECKER_PX)[:, None]
    cols = (torch.arange(width) // CHECKER_PX)[None, :]
    odd = ((rows + cols) % 2).bool()
    light, dark = torch.tensor([0.95, 0.85, 0.55]), torch.tensor([0.15, 0.35, 0.55])
    return torch.where(odd[None], dark[:, None, None], light[:, None, None])


def _photo(name: str) -> Callable[[int, int], torch.Tensor]:
    def make(height: int, width: int) -> torch.Tensor:
        pixels = fit_to_size(load_builtin_photo(name), (height, width))
        return torch.from_numpy(np.ascontiguousarray(to_unit_float(np.ascontiguousarray(pixels)).transpose(2, 0, 1)))

    return make


BUILTIN_TEXTURES: dict[str, Callable[[int, int], torch.Tensor]] = {
    "leaves": _leaves,
    "field": _field,
    "checker": _checker,
    **{name: _photo(name) for name in HELD_OUT_PHOTOS},
}
"""Built-in textures ``(H, W) -> (3, H, W)`` in ``[0, 1]`` (module docstring); ``white`` is added by :func:`surface_reflectance`."""


def builtin_texture_names() -> list[str]:
    return ["white", *BUILTIN_TEXTURES]


def surface_reflectance(spec: str | os.PathLike, height_width: tuple[int, int]) -> torch.Tensor:
    """The reflectance ``(1, 3, H, W)`` of a built-in texture name (module docstring) or of a file in
    projector space (:func:`~edofproj.imaging.surfaces.read_reflectance`: the projector image's size)."""
    name = str(spec)
    height, width = (int(v) for v in height_width)
    if name == "white":
        return torch.ones(1, 3, height, width)
    if name in BUILTIN_TEXTURES:
        return reflectance_from_texture(BUILTIN_TEXTURES[name](height, width), BUILTIN_FLOOR)[None].float()
    if not os.path.exists(name):
        raise EdofprojError(
            f"surface '{name}' is neither a built-in texture ({', '.join(builtin_texture_names())}) nor a file"
        )
    return read_reflectance(name, (height, width))


def _uniform(generator: torch.Generator, low: float, high: float, size: tuple[int, ...] = ()) -> torch.Tensor:
    return low + (high - low) * torch.rand(size, generator=generator, dtype=torch.float64)


class TrainingSurfaces:
    """Random training surfaces (module docstring): ``draw(crop, generator) -> (reflectance (3, crop, crop),
    ambient (3, crop, crop))``, every number from ``generator``."""

    def __init__(self) -> None:
        self.palette = natural_color_palette()
        self.photos = [name for name in BUILTIN_PHOTOS if name not in HELD_OUT_PHOTOS]

    def texture(self, crop: int, generator: torch.Generator) -> torch.Tensor:
        if float(torch.rand((), generator=generator)) < 0.5:
            if float(torch.rand((), generator=generator)) < 0.5:
                radius = max(crop / 64.0, 1.0)
                return textured_dead_leaves_image(crop, crop, radius, 16 * radius, self.palette, generator)
            return smooth_field_image(crop, crop, self.palette, generator, contrast_range=(0.1, 0.35))
        eligible = [n for n in self.photos if min(load_builtin_photo(n).shape[:2]) >= crop]
        if not eligible:
            raise EdofprojError(f"no built-in photograph is {crop} px wide for a training surface; lower data.crop")
        name = eligible[int(torch.randint(0, len(eligible), (), generator=generator))]
        return random_crop(load_builtin_photo(name), crop, generator)

    def draw(self, crop: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        if float(torch.rand((), generator=generator)) < WHITE_PROBABILITY:
            rho = torch.ones(3, crop, crop)
        else:
            floor = float(_uniform(generator, *FLOOR_RANGE))
            tint = _uniform(generator, *TINT_RANGE, size=(3,)).float()
            rho = reflectance_from_texture(self.texture(crop, generator), floor, tint).float()
        level = _uniform(generator, *AMBIENT_RANGE)
        illuminance = (level * (1.0 + AMBIENT_TINT * _uniform(generator, -1.0, 1.0, size=(3,)))).float()
        return rho, rho * illuminance[:, None, None]
