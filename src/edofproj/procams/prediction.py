"""Predict the camera image of a projector image, and score the prediction against a capture.

The model of one capture ``C`` of projector image ``u`` (grey, ``(H, W)`` in ``[0, 1]``):

    C(q) = clip(alpha [D(q) + (B(q) - D(q)) (K * u)(P(q) - o)] + beta, 0, top)

* ``K * u``: ``u`` blurred by the spatially varying PSF of a :class:`.psf_map.PSFMap` (or not at
  all, ``psf_map=None``): the image is cut into tiles of ``tile_px`` with tent weights ``w_t``
  (``sum_t w_t = 1``), and ``K * u = sum_t K_t * (w_t u)`` with ``K_t`` the Gaussian at tile ``t``'s
  centre -- light leaving projector pixel ``x`` spreads with the PSF at ``x``;
* ``P(q) - o``: the projector point camera pixel ``q`` sees (:mod:`.structured_light`, with the
  offset the PSF map estimated), sampled bilinearly (:func:`cv2.remap`). Bilinear interpolation
  between pixel centres is itself a blur, by a tent whose variance is ``f (1 - f)`` at a fractional
  position ``f``, ``1/6`` px^2 on average along each axis; ``K_t`` is therefore the Gaussian of
  covariance ``S_t - I / 6`` (eigenvalues kept at least ``MIN_KERNEL_VARIANCE``), so that blur and
  sampling together spread the light by the measured ``S_t`` and not by ``S_t + I / 6``;
* ``D``, ``B``: what the camera sees at ``q`` with the projector off and fully on (ambient light,
  reflectance, vignetting), from the decoding's dark and bright levels, median-filtered over
  ``flat_filter_px`` camera pixels: a Gray code's per-pixel min and max are partial values where a
  pixel's only dark (or lit) plane has an edge next to it, a thin band that the median removes;
* ``alpha``, ``beta``: the capture's gain and offset (an auto-exposure that changes between frames),
  fitted by least squares over the valid pixels that are neither saturated nor black in the capture.

Scores over the valid region (:func:`score`): PSNR ``10 log10(top^2 / mean (C - C_hat)^2)`` and SSIM
(:func:`skimage.metrics.structural_similarity`, its map averaged over the region).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from skimage.metrics import structural_similarity

from ..errors import EdofprojError
from .psf_map import PSFMap
from .structured_light import CLIPPED_BLACK, SATURATED, CorrespondenceMap

INTERPOLATION_VARIANCE_PX2 = 1.0 / 6.0
"""Mean variance (projector px^2, per axis) of bilinear interpolation between pixel centres."""
MIN_KERNEL_VARIANCE_PX2 = 0.01
"""Smallest eigenvalue (px^2) of a blur kernel's covariance after the interpolation's share is removed."""


def sampling_kernel_covariance(cov: np.ndarray) -> np.ndarray:
    """``S - I / 6`` with its eigenvalues kept at least ``MIN_KERNEL_VARIANCE_PX2``: the Gaussian blur
    that, followed by bilinear sampling, spreads light by ``S`` (module docstring)."""
    values, vectors = np.linalg.eigh(np.asarray(cov, dtype=np.float64))
    values = np.maximum(values - INTERPOLATION_VARIANCE_PX2, MIN_KERNEL_VARIANCE_PX2)
    return (vectors * values) @ vectors.T


def gaussian_kernel(cov: np.ndarray) -> np.ndarray:
    """``(2r + 1, 2r + 1)`` samples of the Gaussian of covariance ``cov`` (px^2) at integer offsets,
    summing to 1; ``r = ceil(4 sigma_max)``."""
    radius = int(math.ceil(4.0 * math.sqrt(max(np.linalg.eigvalsh(cov).max(), 1e-6))))
    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1].astype(np.float64)
    inv = np.linalg.inv(cov)
    kernel = np.exp(-0.5 * (inv[0, 0] * x * x + 2 * inv[0, 1] * x * y + inv[1, 1] * y * y))
    return kernel / kernel.sum()


def blur(image: np.ndarray, psf_map: PSFMap, tile_px: int = 24) -> np.ndarray:
    """``K * u`` for a grey projector image ``(H, W)``, to be sampled bilinearly (module docstring: the
    tiles' kernels are :func:`sampling_kernel_covariance` of the PSF map's covariances)."""
    image = np.asarray(image, dtype=np.float64)
    H, W = image.shape
    if (H, W) != tuple(psf_map.projector_hw):
        raise EdofprojError(
            f"the image is {W}x{H}, the PSF map's projector {psf_map.projector_hw[1]}x{psf_map.projector_hw[0]}"
        )
    centres_y = np.arange(0, H + tile_px - 1, tile_px, dtype=np.float64).clip(max=H - 1)
    centres_x = np.arange(0, W + tile_px - 1, tile_px, dtype=np.float64).clip(max=W - 1)
    centres_y, centres_x = np.unique(centres_y), np.unique(centres_x)
    out = np.zeros_like(image)
    ys, xs = np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64)
    for a, cy in enumerate(centres_y):
        wy = _tent(ys, centres_y, a)
        rows = np.flatnonzero(wy > 0)
        for b, cx in enumerate(centres_x):
            wx = _tent(xs, centres_x, b)
            cols = np.flatnonzero(wx > 0)
            kernel = gaussian_kernel(sampling_kernel_covariance(psf_map.covariance_at(np.array(cx), np.array(cy))))
            r = kernel.shape[0] // 2
            r0, r1 = rows[0], rows[-1] + 1
            c0, c1 = cols[0], cols[-1] + 1
            patch = np.zeros((r1 - r0 + 2 * r, c1 - c0 + 2 * r))
            patch[r : r + r1 - r0, r : r + c1 - c0] = image[r0:r1, c0:c1] * np.outer(wy[r0:r1], wx[c0:c1])
            spread = cv2.filter2D(patch, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            o0, o1 = max(r0 - r, 0), min(r1 + r, H)
            p0, p1 = max(c0 - r, 0), min(c1 + r, W)
            out[o0:o1, p0:p1] += spread[o0 - (r0 - r) : o1 - (r0 - r), p0 - (c0 - r) : p1 - (c0 - r)]
    return out


def _tent(coords: np.ndarray, centres: np.ndarray, index: int) -> np.ndarray:
    """Piecewise-linear weights of centre ``index`` (1 at it, 0 at its neighbours): a partition of unity."""
    one = np.zeros(len(centres))
    one[index] = 1.0
    return np.interp(coords, centres, one)


def sample_at_map(projector_image: np.ndarray, corr: CorrespondenceMap, offset_px=(0.0, 0.0)) -> np.ndarray:
    """``(Hc, Wc)``: the projector image at ``P(q) - o`` for every camera pixel (bilinear), NaN
    where the map is unknown. A map of columns only samples row 0 (images that vary along x only)."""
    image = np.asarray(projector_image, dtype=np.float32)
    if image.shape != tuple(corr.projector_hw):
        raise EdofprojError(
            f"the projector image is {image.shape[1]}x{image.shape[0]}, the map's projector "
            f"{corr.projector_hw[1]}x{corr.projector_hw[0]}"
        )
    valid = corr.valid
    map_x = np.where(valid, corr.proj_x - offset_px[0], -1e6).astype(np.float32)
    if corr.is_complete:
        map_y = np.where(valid, corr.proj_y - offset_px[1], -1e6).astype(np.float32)
    else:
        map_y = np.zeros_like(map_x)
    sampled = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.where(valid, sampled, np.nan).astype(np.float64)


@dataclass
class Prediction:
    """A predicted capture ``image`` ``(Hc, Wc)`` (image units, NaN outside ``region``), the fitted
    ``gain`` and ``offset``, and the scores over ``region``."""

    image: np.ndarray
    region: np.ndarray
    gain: float
    offset: float
    psnr_db: float
    ssim: float


def fit_exposure(model: np.ndarray, capture: np.ndarray, region: np.ndarray) -> tuple[float, float]:
    """``(alpha, beta)`` minimizing ``sum (alpha m + beta - c)^2`` over ``region`` minus the capture's
    saturated and black-clipped pixels (censored: they say only a bound)."""
    use = region & (capture < SATURATED) & (capture > CLIPPED_BLACK) & np.isfinite(model)
    if use.sum() < 2:
        raise EdofprojError("too few unclipped valid pixels to fit the capture's gain and offset")
    A = np.c_[model[use], np.ones(int(use.sum()))]
    (alpha, beta), *_ = np.linalg.lstsq(A, capture[use], rcond=None)
    return float(alpha), float(beta)


def score(prediction: np.ndarray, capture: np.ndarray, region: np.ndarray, top: float = 1.0) -> tuple[float, float]:
    """PSNR (dB, peak ``top``) and mean SSIM over ``region`` (module docstring)."""
    if region.sum() == 0:
        raise EdofprojError("the valid region is empty: nothing to score")
    error = prediction[region] - capture[region]
    mse = float(np.mean(error**2))
    psnr = float("inf") if mse == 0 else 10.0 * math.log10(top**2 / mse)
    filled = np.where(region, prediction, capture)
    _, ssim_map = structural_similarity(capture, filled, data_range=top, full=True)
    return psnr, float(np.mean(ssim_map[region]))


def predict_capture(
    projector_image: np.ndarray,
    capture: np.ndarray,
    corr: CorrespondenceMap,
    dark: np.ndarray,
    bright: np.ndarray,
    psf_map: PSFMap | None = None,
    region: np.ndarray | None = None,
    top: float = 1.0,
    offset_px: tuple[float, float] | None = None,
    flat_filter_px: int = 11,
) -> Prediction:
    """The module docstring's model for a grey projector image ``(H, W)`` in ``[0, 1]`` and a grey
    capture ``(Hc, Wc)`` in image units, scored over ``region`` (default: the map's valid pixels
    where ``B > D``). ``offset_px``: ``o`` (default: the PSF map's, else none)."""
    capture = np.asarray(capture, dtype=np.float64)
    if capture.shape != corr.camera_hw:
        raise EdofprojError(
            f"the capture is {capture.shape[1]}x{capture.shape[0]}, the map's camera {corr.camera_hw[1]}x{corr.camera_hw[0]}"
        )
    if offset_px is None:
        offset_px = (0.0, 0.0) if psf_map is None else (float(psf_map.offset_px[0]), float(psf_map.offset_px[1]))
    light = np.asarray(projector_image, dtype=np.float64)
    if psf_map is not None:
        light = blur(light, psf_map)
    seen = sample_at_map(light, corr, offset_px)
    if flat_filter_px > 1:
        dark = ndimage.median_filter(np.asarray(dark, dtype=np.float64), size=flat_filter_px)
        bright = ndimage.median_filter(np.asarray(bright, dtype=np.float64), size=flat_filter_px)
    model = dark + (bright - dark) * seen
    if region is None:
        region = corr.valid & (bright > dark)
    region = region & np.isfinite(model)
    alpha, beta = fit_exposure(model, capture, region)
    predicted = np.clip(alpha * model + beta, 0.0, top)
    psnr, ssim = score(np.where(region, predicted, 0.0), capture, region, top)
    return Prediction(
        image=np.where(region, predicted, np.nan), region=region, gain=alpha, offset=beta, psnr_db=psnr, ssim=ssim
    )
