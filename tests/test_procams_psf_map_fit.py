"""The dot fit of a PSF map on captures exposed far past saturation, as a lab takes them: colour
channels that saturate at different levels, a camera that clips a black pedestal, and the scatter
of single dots' fits over the grid (virtual captures with known widths)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.lab_manifest import censored_samples, to_grey
from edofproj.procams.psf_map import DotGrid, covariance, measure_psf_map, smooth_covariances, smoothing_dots
from edofproj.procams.structured_light import CorrespondenceMap

SIGMAS = (1.2, 2.4)
THETA = math.radians(80.0)


SPACING = 24


def overexposed_rgb_dots(gains=(1.0, 0.6, 0.35), peak=12.0, pedestal=0.15, noise=0.002, hw=(120, 144),
                         sigma_of=None, seed=0):  # fmt: skip
    """A camera at 2 px per projector px sees single-pixel dots every ``SPACING`` px (no dot's light
    reaches the next one's window), each an anisotropic
    Gaussian (``SIGMAS``, ``THETA``; ``sigma_of(x, y)`` -> (s1, s2) for a field that varies) of peak
    ``peak`` times the full scale in the most sensitive channel; channel ``c`` records
    ``clip(gains[c] peak G - pedestal + noise, 0, 1)`` in 8-bit steps. Returns the RGB capture,
    the map and the projector size."""
    H, W = hw
    v, u = np.mgrid[0 : 2 * H, 0 : 2 * W].astype(float)
    tx, ty = (u - 0.5) / 2, (v - 0.5) / 2
    light = np.zeros_like(tx)
    for y0 in range(0, H, SPACING):
        for x0 in range(0, W, SPACING):
            s1, s2 = SIGMAS if sigma_of is None else sigma_of(x0, y0)
            inv = np.linalg.inv(covariance(s1, s2, THETA))
            dx, dy = tx - x0, ty - y0
            near = (np.abs(dx) < SPACING) & (np.abs(dy) < SPACING)
            light[near] += np.exp(-0.5 * (inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy))[near]
    rng = np.random.default_rng(seed)
    rgb = np.stack([g * peak * light - pedestal + noise * rng.standard_normal(light.shape) for g in gains], axis=-1)
    rgb = np.round(np.clip(rgb, 0.0, 1.0) * 255) / 255
    return rgb, CorrespondenceMap(tx, ty, (H, W)), (H, W)


def truth_widths(s1=SIGMAS[0], s2=SIGMAS[1]):
    cov = covariance(s1, s2, THETA)
    return math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])


def test_a_grey_that_averages_a_saturated_channel_bounds_the_fit_at_its_own_value() -> None:
    """Red saturates well before blue: a grey with only red at the top is a lower bound at its own
    value. Demanding the top of the range there made a false edge at the rim where any channel
    saturates, and the widths came out 10 % too narrow."""
    rgb, corr, hw = overexposed_rgb_dots(pedestal=0.0)
    saturated, clipped = censored_samples(rgb)
    grey = to_grey(rgb)
    assert (saturated & (grey < 0.9)).sum() > 200  # greys with a saturated channel well below the top
    psf_map, _ = measure_psf_map(grey, corr, DotGrid.covering(hw, (SPACING, SPACING)), saturated=saturated, clipped=clipped,
                                 smooth_px=0)  # fmt: skip
    sx, sy = truth_widths()
    inner = psf_map.fitted
    assert inner.sum() >= 20
    assert math.isclose(np.median(psf_map.sigma_x[inner]), sx, rel_tol=0.04)
    assert math.isclose(np.median(psf_map.sigma_y[inner]), sy, rel_tol=0.04)


def test_the_map_smooths_a_patch_of_bad_fits_and_keeps_a_gradient() -> None:
    """Widths that grow steadily across the field (a tilted surface); stray light (a glint) over a
    patch of 2 x 2 dots turns their fits 4-5 times too wide. The map's median over 120 projector px
    (5 x 5 dots) keeps every interior node within 8 % of the truth at its dot; the 3 x 3 median
    (72 px) leaves the patch 19 % off."""

    def sigma_of(x, y):
        f = 1.0 + 0.6 * x / 216.0
        return SIGMAS[0] * f, SIGMAS[1] * f

    rgb, corr, hw = overexposed_rgb_dots(gains=(1.0, 1.0, 1.0), pedestal=0.0, peak=3.0, noise=0.01,
                                         hw=(168, 240), sigma_of=sigma_of)  # fmt: skip
    glint = ((corr.proj_x - 108) / 30) ** 2 + ((corr.proj_y - 84) / 20) ** 2
    rgb = np.clip(rgb + 0.8 * np.exp(-0.5 * glint)[..., None], 0.0, 1.0)
    saturated, clipped = censored_samples(rgb)
    grid = DotGrid.covering(hw, (SPACING, SPACING))
    grey = to_grey(rgb)
    truth = np.array([[truth_widths(*sigma_of(x, y))[1] for x in grid.xs] for y in grid.ys])
    assert smoothing_dots(120, SPACING) == 5 and smoothing_dots(72, SPACING) == 3 and smoothing_dots(0, SPACING) == 1

    def worst(smooth_px):
        m, _ = measure_psf_map(grey, corr, grid, saturated=saturated, clipped=clipped, smooth_px=smooth_px)
        assert m.cov.shape[:2] == truth.shape
        return float(np.abs(m.sigma_y / truth - 1)[1:-1, 1:-1].max())

    assert worst(0) > 3.0  # the glint's dots
    assert worst(72) > 0.15
    assert worst(120) < 0.08
    with pytest.raises(EdofprojError, match="smoothing width"):
        measure_psf_map(grey, corr, grid, saturated=saturated, clipped=clipped, smooth_px=-1.0)


def test_smoothing_keeps_a_covariance_and_a_known_field() -> None:
    cov = np.broadcast_to(covariance(1.0, 2.5, 0.4), (6, 7, 2, 2)).copy()
    cov[2, 3] = covariance(6.0, 0.3, -1.2)  # an outlier
    cov[4, 1] = np.nan  # a dot not fitted
    out = smooth_covariances(cov, 3)
    assert np.all(np.linalg.eigvalsh(out) > 0)
    assert np.allclose(out, covariance(1.0, 2.5, 0.4))
