"""The projection onto a scene: ray-cast depths through the depth-layer renderer.

With the hit mask ``m`` and the axial depth ``z`` of each projector pixel
(:func:`~edofproj.scenes.raycast.cast_scene`),

    render(I) = m * L(m I, z)            (* falloff g, optional; on a textured surface
                                          m * (s ⊙ L(m I, z) + a), :mod:`edofproj.imaging.surfaces`)

where ``L`` is :func:`~edofproj.imaging.depth_layers.render_depth_map`: each *source* pixel is
blurred by the PSF of the surface it lands on (its own depth), so at a depth edge the blur of
the near surface spreads over the far one and the far surface's (smaller or larger) blur over
the near one -- the two sides of an edge differ. Pixels whose ray meets nothing emit into the
void (``m I``: their light is lost) and nothing is seen there (the outer ``m``); light of a hit
pixel that its PSF spreads beyond the object's silhouette is lost too.

The irradiance falloff ``g = cos(theta) (z_ref / d)^2`` (``theta`` the incidence angle, ``d``
the distance from the lens, ``z_ref`` a reference distance, by default the focus distance) is
off by default: it is a smooth gain that a projection-mapping system corrects by radiometric
calibration of its own, it does not depend on the optics, and with it the scores would measure
that gain rather than defocus.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.depth_layers import PSFForDepths, layer_depths_m, render_depth_map
from ..imaging.surfaces import Surface
from .raycast import SceneCast

RANGE_TOLERANCE = 1e-6


def check_scene_depth_range(cast: SceneCast, near_m: float, far_m: float, what: str = "the PSFs") -> None:
    """Raise unless every depth the projector sees lies in ``[near_m, far_m]`` (the PSFs' range)."""
    lo, hi = cast.depth_range_m()
    if lo < near_m * (1 - RANGE_TOLERANCE) or hi > far_m * (1 + RANGE_TOLERANCE):
        raise EdofprojError(
            f"the scene spans {lo * 1e3:.1f}-{hi * 1e3:.1f} mm but {what} cover {near_m * 1e3:.1f}-{far_m * 1e3:.1f} mm"
        )


def filled_depth_m(depth_map_m) -> np.ndarray:
    """A depth map with its missed (NaN) pixels set to the nearest hit depth (their light is zero anyway), float64."""
    depth = np.asarray(depth_map_m, dtype=np.float64)
    hit = np.isfinite(depth)
    if not np.any(hit):
        raise EdofprojError("the depth map has no finite depth: nothing is hit")
    return np.where(hit, depth, depth[hit].min())


def render_masked_depth_map(
    image: torch.Tensor,
    depth_map_m,
    psf_for_depths: Union[PSFForDepths, torch.Tensor],
    layers: Union[int, Sequence[float], np.ndarray],
) -> torch.Tensor:
    """``m * L(m I, z)`` for a depth map ``(H, W)`` whose NaN pixels hit nothing (``m = 0``: light lost)."""
    depth = np.asarray(depth_map_m, dtype=np.float64)
    mask = torch.as_tensor(np.isfinite(depth), dtype=image.dtype, device=image.device)
    return render_depth_map(image.clamp(0.0, 1.0) * mask, filled_depth_m(depth), psf_for_depths, layers=layers) * mask


def scene_layers_m(cast: SceneCast, layers: int) -> np.ndarray:
    """``layers`` depths evenly spaced in 1/z over the depths the projector sees (one for a flat scene)."""
    lo, hi = cast.depth_range_m()
    return layer_depths_m(lo, hi, 1 if lo == hi else max(int(layers), 2))


def relative_irradiance(cast: SceneCast, reference_m: float) -> np.ndarray:
    """``g = cos(theta) (reference_m / d)^2`` per pixel, 0 where missed (module docstring)."""
    if not (np.isfinite(reference_m) and reference_m > 0):
        raise EdofprojError(f"the falloff's reference distance must be positive, got {reference_m:g} m")
    cosine = np.cos(np.radians(np.nan_to_num(cast.incidence_deg, nan=90.0)))
    distance = np.nan_to_num(cast.distance_m, nan=np.inf)
    return np.where(cast.hit, cosine * (reference_m / distance) ** 2, 0.0)


def render_scene(
    image: torch.Tensor,
    cast: SceneCast,
    psf_for_depths: Union[PSFForDepths, torch.Tensor],
    layers: Union[int, Sequence[float], np.ndarray] = 8,
    falloff_reference_m: float | None = None,
    surface: Surface | None = None,
) -> torch.Tensor:
    """What the scene shows when the projector emits ``image (B, C, H, W)`` (module docstring).

    ``layers``: a number of depth layers (spaced in 1/z over the seen depths) or the layer
    depths (then ``psf_for_depths`` may be their PSFs ``(n, C, K, K)``). ``falloff_reference_m``:
    None (no falloff) or ``z_ref`` of ``g``. ``surface``: the objects' reflectance and ambient per
    projector pixel (:mod:`edofproj.imaging.surfaces`: ``m (s ⊙ render + a)``); None: white, no
    ambient. Returns ``(B, C, H, W)``, zero where nothing is hit.
    """
    if image.ndim != 4 or tuple(image.shape[-2:]) != tuple(cast.hit.shape):
        raise EdofprojError(
            f"the image {tuple(image.shape)} does not match the scene's ray cast {tuple(cast.hit.shape)} (H, W)"
        )
    depths = scene_layers_m(cast, layers) if isinstance(layers, (int, np.integer)) else np.asarray(layers, float)
    out = render_masked_depth_map(image, cast.depth_m, psf_for_depths, depths)
    if falloff_reference_m is not None:
        gain = torch.as_tensor(relative_irradiance(cast, falloff_reference_m), dtype=image.dtype, device=image.device)
        out = out * gain
    if surface is not None:
        out = surface.appearance(out) * torch.as_tensor(cast.hit, dtype=out.dtype, device=out.device)
    return out
