"""Projection onto a coloured, textured surface: reflectance multiplies, ambient adds.

A white screen shows the light that reaches it. A real surface (a painted wall, a wooden prop, a
printed fabric) reflects a fraction ``s(x)`` of it per colour, and ambient light ``a(x)`` that
does not come from the projector adds to what is seen. In projector space (one value per
projector pixel and primary, the space of :func:`~edofproj.imaging.projection.project`):

    c(x) = s(x) ⊙ A(L)(x) + a(x)

where ``A(L)`` is the light that reaches the surface when the projector emits ``L``:
:func:`~edofproj.imaging.projection.project` for a flat screen (``PSF ⊛ L`` plus haze),
:func:`~edofproj.imaging.depth_layers.render_depth_map` for a tilted or any depth-mapped screen,
:func:`~edofproj.scenes.render.render_scene` for a 3-D scene. ``⊙`` is the per-pixel, per-colour
product. The surface multiplies *after* the blur: the texture is sharp on the object while the
projection blurs in front of and behind the focus, so the two cannot be swapped (a photometric
correction ``L / s`` is itself blurred by the PSF before the surface sees it).

* ``s`` -- the reflectance ``(B|1, 3, H, W)`` in ``[0, 1]``: 1 is a white screen, which gives
  today's rendering exactly. Values are linear (light reflected per light received), in the
  projector's primaries (a diagonal model: each primary is reflected by its own factor);
* ``a`` -- ambient ``(B|1, 3, H|1, W|1)`` in ``[0, 1]``: light in the same units as the projection
  (1 = what a white surface shows under the full primary), already reflected by the surface
  (it is what the surface shows when the projector is black). An ambient illuminance ``E`` (the
  ``--ambient`` of the commands, ``a = s E``) lies in ``[0, 1]`` too (:func:`check_illuminance`):
  a room brighter than the projector's white leaves the projection under half its contrast, and a
  larger number is a unit mistake (5 for 5 %).

Closed forms (tests): ``s = rho`` uniform and ``a = 0`` gives ``rho * A(L)``; ambient adds
``a`` to every pixel whatever ``L`` is.

Reflectance maps enter as image files in projector space (:func:`read_reflectance`: one pixel per
projector pixel, 8/16-bit image files or a float ``.npy`` array ``(H, W, 3)``), checked by
:func:`check_reflectance` (the size of the projector image, values in ``[0, 1]``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import read_single_numeric_array
from .image_io import read_image

#: Extensions of float reflectance arrays (everything else is read as an image file).
ARRAY_EXTENSIONS = (".npy", ".npz")


def _as_chw(values, what: str) -> torch.Tensor:
    """``(H, W, 3)`` / ``(3, H, W)`` / ``(B, 3, H, W)`` array or tensor -> float32 ``(B|1, 3, H, W)``."""
    tensor = values.detach() if torch.is_tensor(values) else torch.as_tensor(np.asarray(values))
    if tensor.dtype.is_complex or tensor.dtype == torch.bool:
        raise EdofprojError(f"{what} must be an array of real numbers, got {tensor.dtype}")
    tensor = tensor.float()
    if tensor.ndim == 3 and tensor.shape[-1] == 3 and tensor.shape[0] != 3:
        tensor = tensor.permute(2, 0, 1)
    if tensor.ndim == 3:
        tensor = tensor.unsqueeze(0)
    if tensor.ndim != 4 or tensor.shape[1] != 3:
        raise EdofprojError(f"{what} must be an RGB map (H, W, 3) or (B, 3, H, W), got shape {tuple(tensor.shape)}")
    return tensor


def check_reflectance(values, height_width: tuple[int, int] | None, what: str = "the reflectance") -> torch.Tensor:
    """``values`` as a reflectance ``(B|1, 3, H, W)`` float32, or one line saying why not.

    Refused: not RGB, not ``height_width`` (the projector image) when that is given, NaN or
    infinite values, values outside ``[0, 1]`` (a surface cannot reflect more light than it
    receives, nor a negative amount).
    """
    tensor = _as_chw(values, what)
    if height_width is not None and tuple(tensor.shape[-2:]) != tuple(height_width):
        raise EdofprojError(
            f"{what} is {tensor.shape[-2]}x{tensor.shape[-1]} px but the projector image is "
            f"{height_width[0]}x{height_width[1]} (height x width): a reflectance map has one pixel per projector pixel"
        )
    if not bool(torch.isfinite(tensor).all()):
        raise EdofprojError(f"{what} has NaN or infinite values")
    low, high = float(tensor.min()), float(tensor.max())
    if low < 0.0 or high > 1.0:
        raise EdofprojError(f"{what} has values {low:.4g}..{high:.4g}; a reflectance lies in [0, 1]")
    return tensor


#: The largest ambient light (and ambient illuminance): the projector's white (module docstring).
MAX_AMBIENT = 1.0


def check_illuminance(value: float, option: str = "--ambient") -> float:
    """An ambient illuminance ``E`` (a fraction of the projector's white), or one line unless it lies in
    ``[0, MAX_AMBIENT]``: the one check of ``evaluate``, ``render`` and ``procams simulate``."""
    value = float(value)
    if not (math.isfinite(value) and 0.0 <= value <= MAX_AMBIENT):
        raise EdofprojError(
            f"{option} {value:g} must lie in [0, {MAX_AMBIENT:g}]: a fraction of the projector's white (5 % is 0.05)"
        )
    return value


def check_ambient(values, height_width: tuple[int, int] | None, what: str = "the ambient light") -> torch.Tensor:
    """Ambient light as ``(B|1, 3, H|1, W|1)`` float32: a number, an RGB triple or an RGB map, in
    ``[0, MAX_AMBIENT]``."""
    tensor = values.detach().float() if torch.is_tensor(values) else torch.as_tensor(np.asarray(values, float)).float()
    if tensor.ndim == 0:
        tensor = tensor.reshape(1, 1, 1, 1).expand(1, 3, 1, 1)
    elif tensor.ndim == 1:
        if tensor.shape[0] != 3:
            raise EdofprojError(f"{what} must be one number or one per colour (3), got {tensor.shape[0]}")
        tensor = tensor.reshape(1, 3, 1, 1)
    else:
        tensor = _as_chw(tensor, what)
        if height_width is not None and tuple(tensor.shape[-2:]) != tuple(height_width):
            raise EdofprojError(
                f"{what} is {tensor.shape[-2]}x{tensor.shape[-1]} px but the projector image is "
                f"{height_width[0]}x{height_width[1]} (height x width)"
            )
    if not bool(torch.isfinite(tensor).all()) or float(tensor.min()) < 0.0 or float(tensor.max()) > MAX_AMBIENT:
        raise EdofprojError(
            f"{what} must be finite and in [0, {MAX_AMBIENT:g}] (the projector's white), got "
            f"{float(tensor.min()):.4g}..{float(tensor.max()):.4g}"
        )
    return tensor.contiguous()


@dataclass(frozen=True)
class Surface:
    """A surface's reflectance ``s (B|1, 3, H, W)`` in ``[0, 1]`` and ambient ``a (B|1, 3, H|1, W|1) >= 0``.

    Build with :meth:`from_arrays` (checked) or :meth:`white` (today's screen, ``s = 1, a = 0``).
    """

    reflectance: torch.Tensor
    ambient: torch.Tensor

    @classmethod
    def from_arrays(cls, reflectance, ambient=0.0, height_width: tuple[int, int] | None = None) -> "Surface":
        """A checked surface (:func:`check_reflectance`, :func:`check_ambient`)."""
        rho = check_reflectance(reflectance, height_width)
        return cls(rho, check_ambient(ambient, (int(rho.shape[-2]), int(rho.shape[-1]))))

    @classmethod
    def uniform(cls, rho, height_width: tuple[int, int], ambient=0.0) -> "Surface":
        """A uniformly coloured surface: ``rho`` one number or one per colour, in ``[0, 1]``."""
        rho_rgb = np.broadcast_to(np.asarray(rho, dtype=np.float32), (3,))
        values = np.broadcast_to(rho_rgb[:, None, None], (3, *height_width)).copy()
        return cls.from_arrays(values, ambient, height_width)

    @classmethod
    def white(cls, height_width: tuple[int, int]) -> "Surface":
        return cls.uniform(1.0, height_width)

    @property
    def height_width(self) -> tuple[int, int]:
        height, width = (int(v) for v in self.reflectance.shape[-2:])
        return height, width

    def to(self, device=None, dtype=None) -> "Surface":
        return Surface(self.reflectance.to(device=device, dtype=dtype), self.ambient.to(device=device, dtype=dtype))

    def appearance(self, light: torch.Tensor) -> torch.Tensor:
        """``s ⊙ light + a``: what the surface shows under ``light (B, 3, H, W)`` (the light reaching it)."""
        if tuple(light.shape[-2:]) != self.height_width:
            raise EdofprojError(
                f"the surface is {self.height_width[0]}x{self.height_width[1]} px but the image is "
                f"{light.shape[-2]}x{light.shape[-1]} (height x width)"
            )
        rho = self.reflectance.to(device=light.device, dtype=light.dtype)
        return rho * light + self.ambient.to(device=light.device, dtype=light.dtype)

    def range(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per pixel, the least and most a perfectly sharp projector can show: ``a`` and ``a + s``."""
        ambient = self.ambient.expand_as(self.reflectance) if self.ambient.shape[-1] == 1 else self.ambient
        return ambient, ambient + self.reflectance


def on_surface(
    forward: Callable[[torch.Tensor], torch.Tensor], surface: Surface
) -> Callable[[torch.Tensor], torch.Tensor]:
    """The forward model ``L -> s ⊙ forward(L) + a`` (module docstring) for any screen's ``forward``
    (a flat screen, a depth map, a scene); it clamps its input wherever ``forward`` does."""
    return lambda image: surface.appearance(forward(image))


def read_reflectance(path: str | os.PathLike, height_width: tuple[int, int]) -> torch.Tensor:
    """A reflectance map from a file in projector space, ``(1, 3, H, W)`` (:func:`check_reflectance`).

    An image file (PNG, TIFF, JPEG, ...): ``value / (2^bits - 1)``, read as linear reflectance
    (no sRGB decoding: a measured map is written linear); a ``.npy`` file (or ``.npz`` with one
    array): a float array ``(H, W, 3)`` whose values must lie in ``[0, 1]``.
    """
    path = Path(path)
    what = f"texture '{path}'"
    if path.suffix.lower() in ARRAY_EXTENSIONS:
        values = read_single_numeric_array(path, "texture", what, "a reflectance file holds one (H, W, 3)")
        return check_reflectance(values.astype(np.float32), height_width, what)
    return check_reflectance(read_image(path), height_width, what)
