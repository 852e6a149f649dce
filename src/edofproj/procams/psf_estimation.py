"""PSF measurement from captured Bernoulli noise patterns (paper Eq. 13).

With ``B_i`` the projected patterns and ``C_i`` their captures, both as projector *output* light
in projector pixels -- the patterns through the calibrated response ``f`` (exact at the
binary values 0 and 1, which are colour samples), the captures through
:meth:`~edofproj.procams.calibration.ProCamsCalibration.to_output_space` -- each channel's
PSF is

    p = F^-1 { sum_i conj(F{B_i}) F{C_i} / (sum_i |F{B_i}|^2 + eps) },                (13)

with the Tikhonov term ``eps = eps_rel * mean_f sum_i |F{B_i}|^2`` keeping frequencies where
the patterns happen to carry little power from blowing up noise.

**Exact data for Eq. 13.** Eq. 13 assumes ``C_i`` is the *circular* convolution of ``B_i`` with
``p``; a region cut out of a capture is not. With ``m = K//2`` (the window's radius):

1. *Mean removal.* ``B' = B - mean(B)``. At every pixel at least ``m`` from the image border
   (the domain ``D``) ``B (*) p = B' (*) p + mean(B) sum(p)``: the mean only adds a constant.
2. *Masking.* For a region ``R`` with ``R (+) m`` (``R`` grown by ``m``) inside ``D``, on the grid
   ``R (+) m``: ``B~ = B'`` on ``R``, zero elsewhere -- its linear convolution with a ``K x K``
   kernel fits in the grid, so the circular one equals it -- and
   ``C~ = C - (B' 1_{outside R}) (*) p^``, the capture minus the (zero-mean) light of the
   pattern outside ``R`` predicted with the current estimate ``p^``. Then
   ``C~ = B~ (*) p + const`` exactly when ``p^ = p``. The estimate is iterated, each pass
   using the previous one as ``p^`` (the whole image starts from ``p^ = 0``, a patch from the
   whole-image estimate); since ``B'`` is zero-mean noise independent of ``B~``, each pass
   shrinks the error by roughly the square root of the share of light in ``R (+) m`` coming
   from outside ``R``. (A region therefore needs ``R (+) 2m`` inside the image.)
3. *The constant.* The DC term of Eq. 13 is set to zero (it only carries the constant: the
   pattern mean times the PSF sum, the haze, any leftover black level); the kernel outside the
   ``K x K`` window, where a windowed PSF is zero by definition, is then a constant floor,
   whose mean is subtracted.

**Energy.** The colour calibration makes a full field of output 1 read 1 -- haze included --
so the kernel is in units of the emitted light (the pupil energy). Nothing is renormalized:
``sum p`` is the in-window energy ``energy_in_window`` and ``1 - sum p`` the haze, as in
:mod:`edofproj.optics.psf_bank` and :func:`edofproj.imaging.project`. Values are not clipped
at zero (clipping would bias the in-window energy upwards by the noise).

**Patches** (paper Sec. 5.1, Fig. 7): the image minus a border of ``2m`` is tiled by ``N x N``
patches (as many as fit, spread evenly); each is estimated as above, the light from outside it
predicted first with the whole-image estimate, then with its own (the PSF taken as constant
within ``m`` of the patch). The PSF written out is the mean of the patch PSFs (``patch = 0``:
the whole-image estimate alone).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.fft
import torch

from ..errors import EdofprojError
from ..imaging import convolve_same
from ..optics.psf_bank import PSFBank
from ..optics.psf_checks import validate_psf
from .calibration import ProCamsCalibration, warn_if_saturated
from .patterns import PatternManifest

DEFAULT_EPS_REL = 1e-4
DEFAULT_ITERATIONS = 8


def eq13_kernel(patterns: np.ndarray, captures: np.ndarray, eps_rel: float = DEFAULT_EPS_REL) -> np.ndarray:
    """Paper Eq. 13 for one channel: the circular kernel ``(h, w)`` (zero shift at ``[0, 0]``) from
    patterns and captures ``(n, h, w)``, its DC term set to zero."""
    shape = patterns.shape[-2:]
    spectrum_b = scipy.fft.rfft2(patterns, workers=-1)
    spectrum_c = scipy.fft.rfft2(captures, workers=-1)
    numerator = np.sum(np.conj(spectrum_b) * spectrum_c, axis=0)
    power = np.sum(np.abs(spectrum_b) ** 2, axis=0)
    ratio = numerator / (power + eps_rel * power.mean())
    ratio[0, 0] = 0.0  # the DC carries only a constant (module docstring, step 3)
    return scipy.fft.irfft2(ratio, s=shape, workers=-1)


def window_and_floor(kernel: np.ndarray, window: int) -> tuple[np.ndarray, float]:
    """The ``K x K`` window of a circular kernel centred on zero shift, and the kernel's mean outside it."""
    m = window // 2
    rows = np.arange(-m, m + 1) % kernel.shape[0]
    cols = np.arange(-m, m + 1) % kernel.shape[1]
    inside = np.zeros(kernel.shape, dtype=bool)
    inside[np.ix_(rows, cols)] = True
    return kernel[np.ix_(rows, cols)], float(kernel[~inside].mean())


@dataclass
class PSFEstimate:
    """A measured PSF ``(3, K, K)`` (mean of the patches), the per-patch PSFs ``(P, 3, K, K)``,
    their boxes ``(P, 4)`` as ``(y0, y1, x0, x1)`` in projector pixels, and the whole-image estimate."""

    psf: np.ndarray
    patch_psfs: np.ndarray
    patch_boxes: np.ndarray
    whole_image_psf: np.ndarray

    @property
    def energy_in_window(self) -> np.ndarray:
        return self.psf.sum(axis=(-1, -2))

    @property
    def patch_centers_px(self) -> np.ndarray:
        """``(P, 2)`` patch centres as ``(x, y)`` in projector pixels."""
        b = self.patch_boxes.astype(float)
        return np.stack([(b[:, 2] + b[:, 3] - 1) / 2, (b[:, 0] + b[:, 1] - 1) / 2], axis=1)

    def to_bank(self, depth_m: float, pixel_pitch_m: float, description: str = "") -> PSFBank:
        """The measured PSF as a one-depth :class:`~edofproj.optics.psf_bank.PSFBank` (``edofproj psf`` format)."""
        return PSFBank(
            psf=torch.from_numpy(self.psf[None].astype(np.float32)),
            depths_m=np.array([depth_m]),
            pixel_pitch_m=np.array([pixel_pitch_m]),
            description=description,
        )


def _convolve(images: np.ndarray, psf: np.ndarray) -> np.ndarray:
    """Linear 'same' convolution of ``(n, H, W, 3)`` images with a ``(3, K, K)`` PSF."""
    tensor = torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2)))
    with torch.no_grad():
        out = convolve_same(tensor, torch.from_numpy(psf)[None])
    return out.numpy().transpose(0, 2, 3, 1)


def patch_boxes(height: int, width: int, margin: int, patch: int) -> np.ndarray:
    """Boxes ``(P, 4)`` = ``(y0, y1, x0, x1)`` of ``patch x patch`` regions spread evenly over the image
    minus a border of ``margin``; ``patch = 0``: the whole inner image."""
    inner_h, inner_w = height - 2 * margin, width - 2 * margin
    if patch <= 0:
        return np.array([[margin, height - margin, margin, width - margin]])
    if patch > min(inner_h, inner_w):
        raise EdofprojError(
            f"--patch {patch} does not fit the {inner_h}x{inner_w} px (height x width) inner image (the image minus a border of "
            f"{margin} px, twice the window's radius); use --patch {min(inner_h, inner_w)} or smaller, or 0"
        )
    starts_y = np.round(np.linspace(margin, height - margin - patch, max(inner_h // patch, 1))).astype(int)
    starts_x = np.round(np.linspace(margin, width - margin - patch, max(inner_w // patch, 1))).astype(int)
    return np.array([[y, y + patch, x, x + patch] for y in starts_y for x in starts_x])


def _estimate_region(
    patterns: np.ndarray,
    captures: np.ndarray,
    box,
    window: int,
    start: np.ndarray | None,
    iterations: int,
    eps_rel: float,
) -> np.ndarray:
    """Eq. 13 on region ``box`` with the light from outside it removed (module docstring, step 2),
    ``iterations`` times after a first pass that predicts that light with ``start`` (None: no light);
    each later pass predicts it with the region's own previous estimate. Returns ``(3, K, K)``.

    ``patterns``: mean-removed ``B'``. The light reaching ``R (+) m`` comes from the pattern in
    ``R (+) 2m``, so everything is computed on that grid.
    """
    m = window // 2
    y0, y1, x0, x1 = box
    near = (slice(None), slice(y0 - 2 * m, y1 + 2 * m), slice(x0 - 2 * m, x1 + 2 * m))
    inside = np.zeros(patterns.shape[1:3], dtype=patterns.dtype)
    inside[y0:y1, x0:x1] = 1.0
    pattern_near = patterns[near]
    pattern_outside = pattern_near * (1.0 - inside[near[1:]])[None, :, :, None]
    grid = (slice(None), slice(m, -m), slice(m, -m))  # R (+) m within R (+) 2m
    pattern_inside = (pattern_near - pattern_outside)[grid]
    psf = start
    for _ in range(iterations + 1):
        data = captures[near][grid]
        if psf is not None:
            data = data - _convolve(pattern_outside, psf)[grid]
        psf = np.empty((3, window, window))
        for c in range(3):
            kernel = eq13_kernel(pattern_inside[..., c], data[..., c], eps_rel)
            windowed, floor = window_and_floor(kernel, window)
            psf[c] = windowed - floor
    if psf is None:  # only with iterations < 0, which estimate_psf refuses
        raise EdofprojError(f"iterations={iterations} must be >= 0")
    return psf


def estimate_psf(
    patterns: np.ndarray,
    captures: np.ndarray,
    window: int,
    patch: int = 0,
    eps_rel: float = DEFAULT_EPS_REL,
    iterations: int = DEFAULT_ITERATIONS,
) -> PSFEstimate:
    """Measure the PSF from patterns and captures ``(n, H, W, 3)`` in projector output space
    (module docstring). ``window`` K (odd), ``patch`` N px (0: whole image), ``iterations``
    passes that remove the light from outside each region (0: none)."""
    patterns = np.asarray(patterns, dtype=np.float64)
    captures = np.asarray(captures, dtype=np.float64)
    if patterns.shape != captures.shape or patterns.ndim != 4 or patterns.shape[-1] != 3:
        raise EdofprojError(f"patterns {patterns.shape} and captures {captures.shape} must both be (n, H, W, 3)")
    if window < 3 or window % 2 == 0:
        raise EdofprojError(f"--window {window} must be odd and >= 3")
    if eps_rel <= 0 or iterations < 0:
        raise EdofprojError("eps_rel must be > 0 and iterations >= 0")
    if 0 < patch < window:
        raise EdofprojError(f"--patch {patch} must be at least the window ({window} px), or 0 for the whole image")
    H, W = patterns.shape[1:3]
    m = window // 2
    if min(H, W) - 4 * m < window:
        raise EdofprojError(
            f"a {H}x{W} (height x width) image is too small for a {window} px window (needs at least {window + 4 * m} px on each side)"
        )
    patterns = patterns - patterns.mean(axis=(1, 2), keepdims=True)  # B' (module docstring, step 1)
    whole = _estimate_region(patterns, captures, patch_boxes(H, W, 2 * m, 0)[0], window, None, iterations, eps_rel)
    boxes = patch_boxes(H, W, 2 * m, patch)
    if patch <= 0:
        patch_psfs = whole[None]
    else:
        patch_psfs = np.stack(
            [_estimate_region(patterns, captures, box, window, whole, iterations, eps_rel) for box in boxes]
        )
    return PSFEstimate(psf=patch_psfs.mean(axis=0), patch_psfs=patch_psfs, patch_boxes=boxes, whole_image_psf=whole)


def bernoulli_files(manifest: PatternManifest) -> list[str]:
    entries = sorted(manifest.with_role("bernoulli"), key=lambda e: e.index or 0)
    if not entries:
        raise EdofprojError("the pattern manifest has no Bernoulli patterns (role 'bernoulli')")
    return [e.file for e in entries]


def measure_psf(
    manifest: PatternManifest,
    patterns: Mapping[str, np.ndarray],
    captures: Mapping[str, np.ndarray],
    calibration: ProCamsCalibration,
    window: int,
    patch: int = 0,
    eps_rel: float = DEFAULT_EPS_REL,
    iterations: int = DEFAULT_ITERATIONS,
) -> PSFEstimate:
    """The PSF from the Bernoulli patterns ``{file: (H, W, 3) input image}`` and their captures
    ``{file: (Hc, Wc, 3)}``, through the calibration into projector output space."""
    files = bernoulli_files(manifest)
    if calibration.projector_hw != (manifest.height, manifest.width):
        raise EdofprojError(
            f"the calibration is for a {calibration.projector_hw[0]}x{calibration.projector_hw[1]} projector image, "
            f"the patterns are {manifest.height}x{manifest.width} (height x width)"
        )
    warped = {f: calibration.camera_map.warp(captures[f]) for f in files}
    warn_if_saturated(warped)
    pattern_out = np.stack([calibration.color.input_to_output(patterns[f]) for f in files])
    capture_out = np.stack([calibration.color.camera_to_output(warped[f], calibration.black_image) for f in files])
    estimate = estimate_psf(pattern_out, capture_out, window, patch, eps_rel, iterations)
    validate_psf(
        estimate.psf[None],
        source="the measured PSF",
        measured=True,
        fix="check the colour calibration and that the captures match the patterns",
    )
    energy = estimate.energy_in_window
    if np.any(energy > 1.05) or np.any(energy < 0.05):
        warnings.warn(
            f"measured in-window energy {np.round(energy, 3).tolist()} (R, G, B) is implausible (expected 0-1): "
            "check the colour calibration and that the captures match the patterns",
            stacklevel=2,
        )
    return estimate
