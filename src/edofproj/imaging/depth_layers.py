"""Non-planar screens rendered by depth layers: each source pixel is blurred by the PSF of its depth.

The depth map ``z(y, x)`` is approximated by ``n`` layer depths ``z_1 < ... < z_n``. A pixel
between two neighbouring layers is split between them with linear ("hat") weights in
*inverse* depth,

    w_l(y, x) = hat_l(1 / z(y, x)),    sum_l w_l = 1,

because the blur diameter in projector pixels, ``D T W |1/z - 1/v|``
(:meth:`~edofproj.optics.geometry.ProjectorGeometry.blur_diameter_px`), is linear in ``1/z``;
for the same reason the default layers are evenly spaced in ``1/z`` between the nearest and
the farthest depth of the map. The soft split avoids seams where the layer changes. Then

    render(I) = sum_l [ (I_c w_l) (*) p_l  +  (1 - sum p_l) mean(I_c w_l) ],   I_c = clamp(I, 0, 1),

i.e. every layer is projected as in :func:`~edofproj.imaging.projection.project`, and the
light its PSF window loses returns as uniform haze. With one depth everywhere this is
exactly ``project(I, p(z))``. Total light is conserved as in :mod:`.projection`.
"""

from __future__ import annotations

from typing import Callable, Sequence, Union

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import EdofprojError
from .convolution import convolve_same
from .projection import haze_term
from .screens import tilted_plane_depth_map  # noqa: F401  (re-exported: the screen shape used with layers)

PSFForDepths = Callable[[np.ndarray], torch.Tensor]
"""``psf_for_depths(depths_m (n,)) -> (n, C, K, K)``, e.g. ``lambda z: simulator(doe, z)``."""

RANGE_TOLERANCE = 1e-6  # relative slack when checking that depths lie inside the layers' range


def layer_depths_m(depth_min_m: float, depth_max_m: float, layers: int) -> np.ndarray:
    """``layers`` depths evenly spaced in inverse depth from ``depth_min_m`` to ``depth_max_m``.

    One depth when ``depth_min_m == depth_max_m`` (a flat screen needs one layer).
    """
    if int(layers) < 1:
        raise EdofprojError(f"the number of depth layers must be >= 1, got {layers}")
    near, far = float(depth_min_m), float(depth_max_m)
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near <= far):
        raise EdofprojError(f"depth range {near:g}-{far:g} m must be positive, finite and increasing")
    if near == far or int(layers) == 1:
        if near != far:
            raise EdofprojError(
                f"one depth layer cannot represent depths {near * 1e3:g}-{far * 1e3:g} mm; use >= 2 layers"
            )
        return np.array([near])
    inverse = np.linspace(1.0 / near, 1.0 / far, int(layers))
    depths = 1.0 / inverse
    depths[0], depths[-1] = near, far  # exact ends (no rounding through 1/z)
    return depths


def _as_depth_tensor(depth_map_m) -> torch.Tensor:
    depth = torch.as_tensor(np.asarray(depth_map_m) if not torch.is_tensor(depth_map_m) else depth_map_m)
    depth = depth.detach().to(dtype=torch.float64, device="cpu")
    if depth.ndim not in (2, 3):
        raise EdofprojError(f"a depth map must be (H, W) or (B, H, W), got shape {tuple(depth.shape)}")
    if not torch.all(torch.isfinite(depth)) or not torch.all(depth > 0):
        bad = depth[~(torch.isfinite(depth) & (depth > 0))][0].item()
        raise EdofprojError(f"depth map values must be positive and finite, found {bad:g} m")
    return depth


def _check_layer_depths(layer_depths_m: Sequence[float] | np.ndarray) -> np.ndarray:
    depths = np.atleast_1d(np.asarray(layer_depths_m, dtype=float))
    if depths.ndim != 1 or depths.size == 0:
        raise EdofprojError("layer depths must be a non-empty list of depths")
    if not np.all(np.isfinite(depths)) or np.any(depths <= 0):
        raise EdofprojError(f"layer depths must be positive and finite, got {depths.tolist()} m")
    if np.any(np.diff(depths) <= 0):
        raise EdofprojError(f"layer depths must be strictly increasing, got {depths.tolist()} m")
    return depths


def check_within_layers(depth_map_m, layer_depths_m) -> None:
    """Raise unless every depth of the map lies between the first and the last layer depth."""
    depth = _as_depth_tensor(depth_map_m)
    layers = _check_layer_depths(layer_depths_m)
    lo, hi = depth.min().item(), depth.max().item()
    if lo < layers[0] * (1 - RANGE_TOLERANCE) or hi > layers[-1] * (1 + RANGE_TOLERANCE):
        raise EdofprojError(
            f"the depth map spans {lo * 1e3:.1f}-{hi * 1e3:.1f} mm but the PSFs cover "
            f"{layers[0] * 1e3:.1f}-{layers[-1] * 1e3:.1f} mm"
        )


def layer_weights(depth_map_m, layer_depths_m: Sequence[float] | np.ndarray) -> torch.Tensor:
    """Hat weights in inverse depth, ``(n, H, W)`` for an ``(H, W)`` map or ``(B, n, H, W)`` for ``(B, H, W)``.

    For ``z`` between layers ``z_l <= z <= z_{l+1}``:
    ``w_{l+1} = (1/z_l - 1/z) / (1/z_l - 1/z_{l+1})``, ``w_l = 1 - w_{l+1}``, all others 0.
    Depths outside the layers' range take the nearest layer (check with
    :func:`check_within_layers` first). float64.
    """
    depth = _as_depth_tensor(depth_map_m)
    layers = _check_layer_depths(layer_depths_m)
    n = layers.size
    if n == 1:
        return torch.ones((*depth.shape[:-2], 1, *depth.shape[-2:]), dtype=torch.float64)
    # Coordinate that increases with depth and is linear in 1/z: u = -1/z.
    knots = torch.as_tensor(-1.0 / layers, dtype=torch.float64)
    u = -1.0 / depth
    lower = (torch.searchsorted(knots, u.contiguous(), right=True) - 1).clamp(0, n - 2)
    t = ((u - knots[lower]) / (knots[lower + 1] - knots[lower])).clamp(0.0, 1.0)
    weights = (1.0 - t)[..., None] * F.one_hot(lower, n) + t[..., None] * F.one_hot(lower + 1, n)
    return weights.movedim(-1, -3)


def render_depth_map(
    image: torch.Tensor,
    depth_map_m,
    psf_for_depths: Union[PSFForDepths, torch.Tensor],
    layers: Union[int, Sequence[float], np.ndarray] = 8,
    haze: bool = True,
) -> torch.Tensor:
    """Project ``image (B, C, H, W)`` onto a screen whose depth varies per pixel.

    ``depth_map_m``: ``(H, W)`` (all samples) or ``(B, H, W)``, metres (tensor or array).
    ``layers``: a number of layers (evenly spaced in ``1/z`` over the map's range, see
    :func:`layer_depths_m`) or the layer depths themselves (increasing, covering the map).
    ``psf_for_depths``: a callable giving ``(n, C, K, K)`` PSFs for the layer depths (e.g. a
    :class:`~edofproj.optics.psf_bank.PSFSimulator` bound to a DOE), or that tensor itself
    when ``layers`` lists the depths. Returns ``(B, C, H, W)`` (module docstring);
    differentiable in ``image`` and the PSFs.
    """
    if image.ndim != 4:
        raise EdofprojError(f"images must be (B, C, H, W), got shape {tuple(image.shape)}")
    depth = _as_depth_tensor(depth_map_m)
    if tuple(depth.shape[-2:]) != tuple(image.shape[-2:]) or (
        depth.ndim == 3 and depth.shape[0] not in (1, image.shape[0])
    ):
        raise EdofprojError(
            f"depth map has shape {tuple(depth.shape)} but the image is {tuple(image.shape[-2:])} "
            f"(expected (H, W) = {tuple(image.shape[-2:])} or ({image.shape[0]}, H, W))"
        )
    if isinstance(layers, (int, np.integer)):
        depths = layer_depths_m(depth.min().item(), depth.max().item(), int(layers))
    else:
        depths = _check_layer_depths(layers)
    check_within_layers(depth, depths)
    psf = psf_for_depths if torch.is_tensor(psf_for_depths) else psf_for_depths(depths)
    if psf.ndim != 4 or psf.shape[0] != depths.size or psf.shape[-1] != psf.shape[-2]:
        raise EdofprojError(f"expected {depths.size} PSFs (n, C, K, K) for the layers, got shape {tuple(psf.shape)}")
    if psf.shape[1] not in (1, image.shape[1]):
        raise EdofprojError(f"PSFs have {psf.shape[1]} channels but the image has {image.shape[1]}")

    weights = layer_weights(depth, depths).to(dtype=image.dtype, device=image.device)
    if weights.ndim == 3:
        weights = weights.unsqueeze(0)  # (1, n, H, W)
    clamped = image.clamp(0.0, 1.0)
    out = torch.zeros_like(clamped)
    for index in range(depths.size):
        weight = weights[:, index : index + 1]  # (B or 1, 1, H, W)
        if not torch.any(weight > 0):
            continue
        layer_image = clamped * weight
        layer_psf = psf[index : index + 1]
        out = out + convolve_same(layer_image, layer_psf)
        if haze:
            out = out + haze_term(layer_image, layer_psf)
    return out


def bank_layers(bank, depth_map_m) -> tuple[np.ndarray, torch.Tensor]:
    """The depths of a :class:`~edofproj.optics.psf_bank.PSFBank` needed for a depth map, and their PSFs.

    Returns the bank depths from the last one at or before the map's nearest depth to the
    first one at or after its farthest (the layers that bracket the map), for
    ``render_depth_map(image, depth_map_m, psf, layers=depths)``. Raises if the map leaves
    the bank's depth range.
    """
    depth = _as_depth_tensor(depth_map_m)
    order = np.argsort(np.asarray(bank.depths_m, dtype=float))
    bank_depths = np.asarray(bank.depths_m, dtype=float)[order]
    if np.any(np.diff(bank_depths) <= 0):
        raise EdofprojError(f"the PSF file lists a depth twice: {(bank_depths * 1e3).round(3).tolist()} mm")
    lo, hi = depth.min().item(), depth.max().item()
    check_within_layers(depth, bank_depths)
    first = max(int(np.searchsorted(bank_depths, lo * (1 + RANGE_TOLERANCE), side="right")) - 1, 0)
    last = min(int(np.searchsorted(bank_depths, hi * (1 - RANGE_TOLERANCE), side="left")), bank_depths.size - 1)
    chosen = order[first : last + 1]
    return bank_depths[first : last + 1], bank.psf[torch.as_tensor(chosen)]
