"""The radial engine on a design's own rings: exact for any piecewise-constant profile (docs/physics.md section 5).

The reference integrates the Hankel transform of the kinoform's pupil function by Gauss-Legendre
quadrature on each design ring (scipy's J0, no closed-form ring moments, no defocus expansion) and
integrates the intensity over each pixel square by 2-D Gauss-Legendre quadrature of its cubic
spline: independent of the engine's ring moments and pixel weights.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss
from scipy.interpolate import CubicSpline
from scipy.special import j0

from edofproj.doe.storage import TabulatedRadialDOE
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.materials import height_2pi_m, refractive_index
from edofproj.optics.radial_engine import RadialPSFEngine, split_ring_edges

GEO = ProjectorGeometry()
R = GEO.aperture_radius_m
DESIGN_LAMBDA = 550e-9
LEVELS = 16


def kinoform() -> tuple[np.ndarray, np.ndarray]:
    """A 16-level diffractive lens (f = 2 m at 550 nm) with its rings at the exact level edges
    r_j = sqrt(j lambda f / 8): 89 rings, 371 um wide at the centre, 20 um at the rim, and a
    last ring up to the rim."""
    r = np.sqrt(np.arange(1, 200) * DESIGN_LAMBDA * 2.0 / 8)
    edges = np.concatenate([[0.0], r[r < R - 15e-6], [R]])
    level = (-np.arange(len(edges) - 1)) % LEVELS
    return edges, level * height_2pi_m(DESIGN_LAMBDA) / LEVELS


def reference_psf(edges, height, lam, z, window) -> np.ndarray:
    """Pixel energies (K, K) of the piecewise-constant pupil, by quadrature (module docstring)."""
    g, w = leggauss(48)
    r, wr, h = [], [], []
    for a, b, hk in zip(edges[:-1], edges[1:], height):
        cuts = np.linspace(a, b, int(np.ceil((b - a) / 20e-6)) + 1)  # pieces <= 20 um
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            r.append((lo + hi) / 2 + g * (hi - lo) / 2)
            wr.append(w * (hi - lo) / 2)
            h.append(np.full(g.size, hk))
    r, wr, h = map(np.concatenate, (r, wr, h))
    phase = 2 * np.pi * (refractive_index(lam) - 1) * h / lam + np.pi * r**2 * (1 / z - 1 / GEO.focus_distance_m) / lam
    pupil = np.exp(1j * phase) * r * wr
    tw = lam * GEO.throw_width_m
    rho = np.arange(0.0, (window // 2 + 0.5) * np.sqrt(2) + 0.1, tw / (2 * R) / 32)  # 1/32 diffraction unit
    field = np.concatenate([j0(2 * np.pi * np.outer(part, r) / tw) @ pupil for part in np.array_split(rho, 20)])
    intensity = CubicSpline(rho, np.abs(field) ** 2 * (2 * np.pi / tw) ** 2 / (np.pi * R**2))
    t, tw8 = leggauss(10)
    sub = np.linspace(-0.5, 0.5, 21)
    half = np.diff(sub)[:, None] / 2
    nodes = ((sub[:-1, None] + sub[1:, None]) / 2 + t[None, :] * half).ravel()
    weights = (tw8[None, :] * half).ravel()
    c = window // 2
    out = np.empty((window, window))
    for i in range(window):
        for j in range(window):
            X, Y = np.meshgrid(nodes + j - c, nodes + i - c)
            out[i, j] = np.einsum("ij,i,j->", intensity(np.hypot(X, Y)), weights, weights)
    return out


@pytest.mark.filterwarnings("ignore::edofproj.errors.BlurExceedsWindowWarning")  # the window is compared
@pytest.mark.parametrize(("lam", "depth_m"), [(460e-9, 0.5), (550e-9, 0.3)])
def test_a_kinoform_with_unequal_rings_matches_an_independent_hankel_integration(lam, depth_m):
    edges, height = kinoform()
    doe = TabulatedRadialDOE(edges, height, R, DESIGN_LAMBDA, LEVELS)
    psf = RadialPSFEngine(GEO, [lam], 11, 1024).psf(doe, [depth_m])[0, 0].numpy()
    exact = reference_psf(edges, height, lam, depth_m, 11)
    assert np.abs(psf - exact).sum() < 2e-4  # resampled rings: 0.3-0.75 %; the goal: 0.1 %
    assert psf.max() / exact.max() == pytest.approx(1.0, abs=1e-3)


def test_split_edges_keep_the_engine_rings_and_add_the_design_edges_inside_the_pupil():
    base = np.linspace(0.0, 1.0, 5)
    split = split_ring_edges(base, [0.1, 0.25 + 1e-12, 0.6, 1.0, 1.5, -0.2])
    np.testing.assert_allclose(split, [0.0, 0.1, 0.25, 0.5, 0.6, 0.75, 1.0])


def test_designs_without_their_own_rings_use_the_engine_rings():
    engine = RadialPSFEngine(GEO, [DESIGN_LAMBDA], 5, 64)
    centres, kernel = engine.rings_for(None)
    assert centres is engine.ring_centres_t and kernel is engine.kernel
    edges, height = kinoform()
    centres, kernel = engine.rings_for(TabulatedRadialDOE(edges, height, R, DESIGN_LAMBDA, LEVELS))
    assert len(centres) == kernel.shape[0] > 32  # 32 engine rings split at the design's edges
