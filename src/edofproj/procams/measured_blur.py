"""The blur a PSF map measured, as a linear operator on projector images (the forward model that
compensation from a PSF map inverts).

A :class:`.psf_map.PSFMap` gives the PSF's covariance ``S(x)`` (projector px^2) at every projector
point. The blur of a projector image ``u`` is taken as the source form of
:class:`edofproj.imaging.field_varying.FieldVaryingBlur`: nodes on a uniform grid over the projector
image (``node_spacing_px`` apart, the first and last rows and columns included), node ``g`` with the
kernel ``h_g`` = the Gaussian of covariance ``S(node)`` sampled at integer offsets out to ``4 sigma``
and normalized to 1 (:func:`.prediction.gaussian_kernel`; the window is at most ``4 sigma`` of the
map's 99th-percentile width, :func:`window_radius_px`: the rare wider kernel, a fit at the edge of
the projection, is cut there), each pixel's PSF interpolated bilinearly between the kernels of the
nodes around it:

    (A u)(y) = sum_x u(x) h(y - x; x),       h(.; x) = sum_g w_g(x) h_g.

The measured ``S`` is the spread of one lit pixel in projector coordinates, which is what blurring the
projector image pixel by pixel needs (no share is removed for camera sampling: that is
``procams predict``'s business, which samples the blurred image at camera pixels).

**Colours.** A file with per-colour maps (``red``, ``green``, ``blue``) blurs each image plane with
its colour's map (:func:`.psf_map.psf_maps_for_rgb`: a colour without its own map takes the white
``mean`` map); a file with one map blurs every plane with it (one kernel channel).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.field_varying import FieldVaryingBlur, node_centres_px
from .prediction import gaussian_kernel
from .psf_map import PSFMap, is_kernel_map_file, load_psf_maps, psf_maps_for_rgb

DEFAULT_NODE_SPACING_PX = 16
"""Spacing (projector px) of the nodes whose kernels are interpolated."""
DEFAULT_RANK_TOLERANCE = 1e-2
"""Relative error (Frobenius, all node kernels) of the low-rank form of the node kernels."""
WINDOW_QUANTILE = 0.99
"""The kernels' common window is ``4 sigma`` of this quantile of the map's widths (:func:`window_radius_px`)."""


def node_kernels(
    psf_map: PSFMap, centres_y_px: np.ndarray, centres_x_px: np.ndarray, radius_px: int | None = None
) -> np.ndarray:
    """``(Gy, Gx, K, K)`` float64: the Gaussian of the map's covariance at every node (module docstring),
    each out to its own ``4 sigma``, zero-padded to the largest; ``radius_px`` caps the window's
    radius (``K = 2 radius + 1``; a wider Gaussian is cut there and renormalized)."""
    yy, xx = np.meshgrid(centres_y_px, centres_x_px, indexing="ij")
    cov = psf_map.covariance_at(xx, yy)  # (Gy, Gx, 2, 2)
    kernels = [[gaussian_kernel(cov[i, j]) for j in range(len(centres_x_px))] for i in range(len(centres_y_px))]
    size = max(k.shape[0] for row in kernels for k in row)
    if radius_px is not None:
        size = min(size, 2 * int(radius_px) + 1)
    out = np.zeros((len(centres_y_px), len(centres_x_px), size, size))
    for i, row in enumerate(kernels):
        for j, k in enumerate(row):
            if k.shape[0] > size:
                c = (k.shape[0] - size) // 2
                k = k[c : c + size, c : c + size] / k[c : c + size, c : c + size].sum()
            m = (size - k.shape[0]) // 2
            out[i, j, m : m + k.shape[0], m : m + k.shape[0]] = k
    return out


def window_radius_px(planes, quantile: float = WINDOW_QUANTILE) -> int:
    """``ceil(4 sigma)`` of the ``quantile`` of the maps' largest widths (the major axes of their
    covariances over every grid point): the window every node kernel gets. A fit that ran to the
    largest width :data:`.psf_map.MAX_SIGMA_PX` (a dot at the projection's edge) would otherwise set a
    window of ``160 px`` for the whole map, and with it the work of every application."""
    widths = np.concatenate([np.sqrt(np.linalg.eigvalsh(p.cov)[..., -1]).ravel() for p in planes])
    return int(np.ceil(4.0 * float(np.quantile(widths, quantile))))


def measured_blur(
    maps: PSFMap | Mapping[str, PSFMap],
    node_spacing_px: int = DEFAULT_NODE_SPACING_PX,
    rank_tolerance: float = DEFAULT_RANK_TOLERANCE,
) -> FieldVaryingBlur:
    """The operator ``A`` of the module docstring for the projector of ``maps`` (one map, or a file's
    maps by channel from :func:`.psf_map.load_psf_maps`): kernel channels 3 (R, G, B) when a colour has
    its own map, else 1. Images ``(B, C, H, W)`` at the map's ``projector_hw``."""
    if isinstance(maps, PSFMap):
        planes = [maps]
    else:
        if not maps:
            raise EdofprojError("no PSF map")
        rgb = psf_maps_for_rgb(dict(maps))
        planes = list(rgb) if any(c in maps for c in ("red", "green", "blue")) else [rgb[0]]
    hw = tuple(planes[0].projector_hw)
    if any(tuple(p.projector_hw) != hw for p in planes):
        raise EdofprojError("the PSF maps are for projectors of different sizes")
    cy, cx = node_centres_px(hw[0], node_spacing_px), node_centres_px(hw[1], node_spacing_px)
    radius = window_radius_px(planes)
    per_plane = [node_kernels(p, cy, cx, radius) for p in planes]
    size = max(k.shape[-1] for k in per_plane)
    kernels = np.zeros((len(cy), len(cx), len(planes), size, size))
    for c, k in enumerate(per_plane):
        m = (size - k.shape[-1]) // 2
        kernels[:, :, c, m : m + k.shape[-1], m : m + k.shape[-1]] = k
    return FieldVaryingBlur(torch.from_numpy(kernels), cy, cx, (int(hw[0]), int(hw[1])), rank_tolerance)


def map_file_blur(
    path, node_spacing_px: int = DEFAULT_NODE_SPACING_PX, rank_tolerance: float = DEFAULT_RANK_TOLERANCE
) -> FieldVaryingBlur:
    """The operator of a PSF map file of either kind: a Gaussian PSF map (:func:`measured_blur`, nodes
    ``node_spacing_px`` apart) or a kernel map (:meth:`.kernel_map.KernelMap.blur`, its own nodes)."""
    from .kernel_map import KernelMap

    if is_kernel_map_file(path):
        return KernelMap.load(path).blur(rank_tolerance)
    return measured_blur(load_psf_maps(path), node_spacing_px, rank_tolerance)
