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
  and ``delta``: how much the dark level changed since the map's session beyond that gain (ambient
  light, the projector's black: ``D`` is the map's, not the capture's black), the term
  ``delta (D(q) - mean D)``, zero for a flat ``D``. So the capture is modelled as
  ``alpha m + delta (D - mean D) + beta`` with ``m`` the bracket above. The three are fitted by
  least squares over the valid pixels with the capture's saturated and black-clipped pixels
  censored: a pixel clipped to black says only that the model is ``<= 0`` there and a saturated one
  only that it is ``>= top``, residuals ``max(0, model)`` and ``max(0, top - model)`` (a dot
  capture is mostly black: those pixels fix the dark level); ``alpha > 0``.

**Registration.** ``o`` is one choice for the blurred and the unblurred model alike
(:func:`registration_offset`): the given offset, else the PSF map's, else none; ``blur_psf=False``
predicts without blur at the PSF map's registration, so that the two differ by the blur alone.

**Another blur.** ``light_blur``, any operator ``(H, W) -> (H, W)`` on the projector image (another
blur model, e.g. the per-pixel kernels of :mod:`.lab_kernels`), replaces ``K *`` above at the same
registration, so that two blur models of one projector can be compared on the same capture.

Scores over the valid region (:func:`score`): PSNR ``10 log10(top^2 / mean (C - C_hat)^2)`` and SSIM
(:func:`skimage.metrics.structural_similarity`, its map averaged over the region).
"""

from __future__ import annotations

import math
from collections.abc import Callable
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
    ``gain`` and ``offset``, the scores over ``region`` and the registration ``offset_px`` ``o`` used."""

    image: np.ndarray
    region: np.ndarray
    gain: float
    offset: float
    psnr_db: float
    ssim: float
    offset_px: tuple[float, float] = (0.0, 0.0)


def fit_exposure(model: np.ndarray, capture: np.ndarray, region: np.ndarray, top: float = 1.0) -> tuple[float, float]:
    """``(alpha, beta)``, ``alpha > 0``, minimizing the module docstring's censored squares over
    ``region``: unclipped pixels ``(alpha m + beta - c)^2``, black-clipped ``max(0, alpha m + beta)^2``,
    saturated ``max(0, top - alpha m - beta)^2``."""
    alpha, beta = censored_linear_fit([np.asarray(model, dtype=np.float64)], capture, region, top)
    return alpha, beta


def censored_linear_fit(
    columns: list[np.ndarray], capture: np.ndarray, region: np.ndarray, top: float = 1.0
) -> tuple[float, ...]:
    """``(a_1, ..., a_n, beta)`` of ``c ~ sum_i a_i x_i + beta`` over ``region`` (``columns`` ``x_i``
    like ``capture``), ``a_1 > 0``, with the capture's black-clipped and saturated pixels censored
    (module docstring; a clipped pixel is at most ``CLIPPED_BLACK``, a saturated one at least
    ``SATURATED top``). Starts from the least squares over the unclipped pixels."""
    from scipy.optimize import least_squares

    capture = np.asarray(capture, dtype=np.float64)
    usable = region & np.isfinite(capture)
    for x in columns:
        usable = usable & np.isfinite(x)
    high, low = usable & (capture >= SATURATED), usable & (capture <= CLIPPED_BLACK)
    free = usable & ~high & ~low
    if free.sum() < len(columns) + 1:
        raise EdofprojError(
            f"too few valid pixels between black and saturation in the capture ({int(free.sum())} of "
            f"{int(usable.sum())}) to fit its gain and offset: is the capture under- or over-exposed?"
        )
    design = {name: np.stack([x[mask] for x in columns] + [np.ones(int(mask.sum()))], axis=1)
              for name, mask in (("free", free), ("high", high), ("low", low))}  # fmt: skip
    target = capture[free]
    x0, *_ = np.linalg.lstsq(design["free"], target, rcond=None)
    if x0[0] > 0 and not high.any() and not low.any():
        return tuple(float(v) for v in x0)
    if x0[0] <= 0:  # the unclipped pixels alone do not see the light: start from the capture's range
        x0 = np.zeros(len(columns) + 1)
        span = float(np.ptp(columns[0][usable])) or 1.0
        x0[0] = max(float(np.ptp(target)), 1e-3) / span
        x0[-1] = float(target.min() - x0[0] * columns[0][free].min())

    def residuals(p: np.ndarray) -> np.ndarray:
        return np.concatenate([design["free"] @ p - target, np.maximum(0.0, design["low"] @ p - CLIPPED_BLACK),
                               np.maximum(0.0, SATURATED * top - design["high"] @ p)])  # fmt: skip

    lower = np.full(len(x0), -np.inf)
    lower[0] = 1e-9
    x0[0] = max(x0[0], 1e-6)
    result = least_squares(
        residuals, x0, bounds=(lower, np.full(len(x0), np.inf)), x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12
    )
    return tuple(float(v) for v in result.x)


def registration_offset(psf_map: PSFMap | None, offset_px: tuple[float, float] | None) -> tuple[float, float]:
    """``o``: ``offset_px`` when given (finite, inside the projector), else the PSF map's estimate, else none."""
    if offset_px is not None:
        if len(offset_px) != 2 or not all(math.isfinite(v) for v in offset_px):
            raise EdofprojError(f"the map offset {tuple(offset_px)} is not two finite numbers of projector px")
        return float(offset_px[0]), float(offset_px[1])
    if psf_map is not None:
        return float(psf_map.offset_px[0]), float(psf_map.offset_px[1])
    return 0.0, 0.0


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
    blur_psf: bool = True,
    light_blur: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Prediction:
    """The module docstring's model for a grey projector image ``(H, W)`` in ``[0, 1]`` and a grey
    capture ``(Hc, Wc)`` in image units, scored over ``region`` (default: the map's valid pixels
    where ``B > D``). ``offset_px``: ``o`` (:func:`registration_offset`); ``blur_psf`` False: the
    PSF map registers but does not blur; ``light_blur``: the blur of the projector image ``(H, W) ->
    (H, W)`` used instead of the PSF map's (module docstring)."""
    capture = np.asarray(capture, dtype=np.float64)
    if capture.shape != corr.camera_hw:
        raise EdofprojError(
            f"the capture is {capture.shape[1]}x{capture.shape[0]}, the map's camera {corr.camera_hw[1]}x{corr.camera_hw[0]}"
        )
    offset_px = registration_offset(psf_map, offset_px)
    H, W = corr.projector_hw
    if abs(offset_px[0]) >= W or abs(offset_px[1]) >= H:
        raise EdofprojError(
            f"the map offset ({offset_px[0]:g}, {offset_px[1]:g}) projector px moves every camera pixel off the "
            f"{W}x{H} projector: an offset is a few px (the PSF map's estimate, or 0 0 for a Gray-code map)"
        )
    light = np.asarray(projector_image, dtype=np.float64)
    if light_blur is not None:
        blurred = np.asarray(light_blur(light), dtype=np.float64)
        if blurred.shape != light.shape:
            raise EdofprojError(f"the blur turned a {light.shape} projector image into {blurred.shape}")
        light = blurred
    elif psf_map is not None and blur_psf:
        light = blur(light, psf_map)
    seen = sample_at_map(light, corr, offset_px)
    if flat_filter_px > 1:
        dark = ndimage.median_filter(np.asarray(dark, dtype=np.float64), size=flat_filter_px)
        bright = ndimage.median_filter(np.asarray(bright, dtype=np.float64), size=flat_filter_px)
    model = dark + (bright - dark) * seen
    if region is None:
        region = corr.valid & (bright > dark)
    region = region & np.isfinite(model)
    # the dark level's own change between sessions: D about its mean over the region (zero for a flat D)
    ambient = dark - float(np.mean(dark[region])) if region.any() else np.zeros_like(dark)
    alpha, delta, beta = censored_linear_fit([model, ambient], capture, region, top)
    predicted = np.clip(alpha * model + delta * ambient + beta, 0.0, top)
    psnr, ssim = score(np.where(region, predicted, 0.0), capture, region, top)
    return Prediction(
        image=np.where(region, predicted, np.nan), region=region, gain=alpha, offset=beta, psnr_db=psnr, ssim=ssim,
        offset_px=offset_px,
    )  # fmt: skip
