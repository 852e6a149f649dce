"""Exact pixel-area integration of a radially symmetric intensity.

A PSF pixel holds the energy that falls on its square, not the intensity at its centre:
near focus the diffraction spot is far smaller than a pixel. For a radial intensity I(rho)
tabulated on annuli [e_k, e_{k+1}) (constant on each annulus), the energy on pixel p is

    E_p = sum_k I_k * ( A_p(e_{k+1}) - A_p(e_k) ),

where A_p(rho) is the area of the disk of radius rho (centred on the optical axis)
intersected with the pixel square. A_p has a closed form, built from the area of the disk
inside the corner region [0, X] x [0, Y]:

    g(X, Y) = Y * min(X, x*) + S(X) - S(min(X, x*)),   x* = sqrt(rho^2 - Y^2),
    S(x) = (x sqrt(rho^2 - x^2) + rho^2 asin(x / rho)) / 2,

with X, Y clipped to rho, extended to signed corners and combined by inclusion-exclusion.
"""

from __future__ import annotations

import numpy as np


def _corner_area(X: np.ndarray, Y: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Signed area of {x^2 + y^2 <= rho^2} within the rectangle between (0, 0) and (X, Y)."""
    sign = np.sign(X) * np.sign(Y)
    X = np.minimum(np.abs(X), rho)
    Y = np.minimum(np.abs(Y), rho)
    rho_safe = np.where(rho > 0, rho, 1.0)

    def S(x):
        return 0.5 * (x * np.sqrt(np.maximum(rho**2 - x**2, 0.0)) + rho**2 * np.arcsin(np.clip(x / rho_safe, -1, 1)))

    x_star = np.sqrt(np.maximum(rho**2 - Y**2, 0.0))
    xm = np.minimum(X, x_star)
    area = Y * xm + S(X) - S(xm)
    return sign * np.where(rho > 0, area, 0.0)


def disk_rectangle_area(rho, x0, x1, y0, y1) -> np.ndarray:
    """Area of the disk of radius ``rho`` (centred at the origin) inside [x0,x1] x [y0,y1].

    Broadcasts over all arguments.
    """
    rho = np.asarray(rho, dtype=float)
    return _corner_area(x1, y1, rho) - _corner_area(x0, y1, rho) - _corner_area(x1, y0, rho) + _corner_area(x0, y0, rho)


def octant_pixels(window: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique pixels of a radially symmetric K x K window and the map back to K x K.

    Returns ``offsets`` (n_unique, 2) with a >= b >= 0 (pixel offsets from the centre) and
    ``index`` (K, K) giving for each window pixel the row of its unique representative.
    """
    c = window // 2
    offsets = np.array([(a, b) for a in range(c + 1) for b in range(a + 1)], dtype=int)
    lookup = {(int(a), int(b)): i for i, (a, b) in enumerate(offsets)}
    d = np.abs(np.arange(window) - c)
    index = np.empty((window, window), dtype=np.int64)
    for i in range(window):
        for j in range(window):
            index[i, j] = lookup[(max(d[i], d[j]), min(d[i], d[j]))]
    return offsets, index


def _pixels_crossing(offsets: np.ndarray, a_edge: np.ndarray, b_edge: np.ndarray):
    """Yield ``(p, (x0, x1, y0, y1), sel)`` for each pixel ``p`` of ``offsets`` whose radial span some
    interval crosses (:func:`_crossing_ranges`): its square and the indices ``sel`` of those intervals."""
    x0, x1, y0, y1, lo, hi = _crossing_ranges(offsets, a_edge, b_edge)
    for p in np.nonzero(hi > lo)[0]:
        yield p, (x0[p], x1[p], y0[p], y1[p]), np.arange(lo[p], hi[p])


def hat_pixel_weights(rho_px: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``W`` (n_unique_pixels, n_rho) with ``E_p = sum_k W[p, k] I(rho_k)`` for an
    intensity ``I`` that is piecewise linear between the samples ``rho_px`` (increasing, from 0).

    With hat functions h_k, ``W[p, k] = int h_k(rho) dA_p(rho)``; on an interval [a, b]
    integration by parts gives ``Abar - A_p(a)`` to the left hat and ``A_p(b) - Abar`` to the
    right one, where ``Abar`` is the mean of A_p on [a, b] (Simpson's rule; A_p is smooth).
    Only intervals that cross the pixel's radial span are evaluated.
    """
    offsets, index = octant_pixels(window)
    rho = np.asarray(rho_px, dtype=float)
    a_edge, b_edge = rho[:-1], rho[1:]
    weights = np.zeros((len(offsets), len(rho)))
    for p, (x0, x1, y0, y1), sel in _pixels_crossing(offsets, a_edge, b_edge):
        a, b = a_edge[sel], b_edge[sel]
        area_a = disk_rectangle_area(a, x0, x1, y0, y1)
        area_b = disk_rectangle_area(b, x0, x1, y0, y1)
        area_m = disk_rectangle_area(0.5 * (a + b), x0, x1, y0, y1)
        mean = (area_a + 4 * area_m + area_b) / 6
        np.add.at(weights[p], sel, mean - area_a)
        np.add.at(weights[p], sel + 1, area_b - mean)
    return weights, index


def cubic_pixel_weights(rho_px: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``W`` (n_unique_pixels, n_rho) with ``E_p = sum_k W[p, k] I(rho_k)`` for the intensity
    interpolated between the samples ``rho_px`` (increasing, from 0, at least 4) by cubics: on
    [rho_k, rho_k+1] the Lagrange cubic through the samples k-1..k+2 (k..k+3 at the first interval,
    the last four at the end).

    With ``L_j`` the cubic's basis on an interval [a, b], integration by parts gives
    ``int_a^b L_j dA_p = L_j(b) A_p(b) - L_j(a) A_p(a) - int_a^b L_j'(rho) A_p(rho) drho``; ``L_j(a)``,
    ``L_j(b)`` are 0 or 1 (a and b are samples) and the last integral, of a quadratic times the smooth
    ``A_p``, takes 3-point Gauss-Legendre (exact when ``A_p`` is a cubic). Only intervals that cross the
    pixel's radial span are evaluated. Against the hat functions' piecewise-linear intensity
    (:func:`hat_pixel_weights`) the PSF error from the radial sampling drops about eightfold.
    """
    offsets, index = octant_pixels(window)
    rho = np.asarray(rho_px, dtype=float)
    n = len(rho)
    if n < 4:
        return hat_pixel_weights(rho, window)
    k = np.arange(n - 1)
    first = np.clip(k - 1, 0, n - 4)
    stencil = first[:, None] + np.arange(4)[None, :]  # (n_int, 4)
    x = rho[stencil]  # stencil nodes
    a_edge, b_edge = rho[:-1], rho[1:]
    g, gw = np.polynomial.legendre.leggauss(3)
    nodes = 0.5 * (a_edge + b_edge)[:, None] + 0.5 * (b_edge - a_edge)[:, None] * g[None, :]  # (n_int, 3)
    gweights = 0.5 * (b_edge - a_edge)[:, None] * gw[None, :]
    # L_j'(t) = sum_{m != j} 1 / (x_j - x_m) prod_{l != j, m} (t - x_l) / (x_j - x_l), at the Gauss nodes
    deriv = np.zeros((n - 1, 4, 3))
    for j in range(4):
        for m in range(4):
            if m == j:
                continue
            term = 1.0 / (x[:, j] - x[:, m])[:, None]
            for q in range(4):
                if q not in (j, m):
                    term = term * (nodes - x[:, q : q + 1]) / (x[:, j] - x[:, q])[:, None]
            deriv[:, j, :] += term
    deriv *= gweights[:, None, :]
    # all pixels at once: pixel p needs the intervals lo[p] .. hi[p] - 1 that cross its radial span
    # (contiguous); the (pixel, interval) pairs are listed pixel by pixel, then interval by interval
    x0, x1, y0, y1, lo, hi = _crossing_ranges(offsets, a_edge, b_edge)
    count = hi - lo
    pixel = np.repeat(np.arange(len(offsets)), count)
    interval = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - lo, count)
    square = (x0[pixel], x1[pixel], y0[pixel], y1[pixel])
    area_a = disk_rectangle_area(a_edge[interval], *square)  # A_p at each interval's ends
    area_b = disk_rectangle_area(b_edge[interval], *square)
    area_g = disk_rectangle_area(nodes[interval], *(c[:, None] for c in square))  # (pairs, 3)
    inner = np.einsum("sjg,sg->sj", deriv[interval], area_g)  # (pairs, 4)
    row = pixel * n
    weights = np.zeros(len(offsets) * n)
    np.add.at(weights, row + interval + 1, area_b)
    np.add.at(weights, row + interval, -area_a)
    weights -= np.bincount((row[:, None] + stencil[interval]).ravel(), inner.ravel(), minlength=len(weights))
    return weights.reshape(len(offsets), n), index


def _crossing_ranges(offsets: np.ndarray, a_edge: np.ndarray, b_edge: np.ndarray):
    """The pixels' squares and the radial intervals crossing them: ``(x0, x1, y0, y1, lo, hi)``, each
    ``(P,)`` for the pixels ``offsets`` (``(ia, ib)`` with ``ia >= ib >= 0``, :func:`octant_pixels`).
    Pixel p's square is ``[ia - 1/2, ia + 1/2] x [ib - 1/2, ib + 1/2]``; the intervals
    ``[a_edge, b_edge]`` (both increasing) that cross its radial span ``(near, far)`` (``near``: the
    square's closest point to the centre, 0 for the centre pixel; ``far``: its farthest corner) are
    ``lo .. hi - 1`` (``hi == lo``: none)."""
    ia, ib = offsets[:, 0].astype(float), offsets[:, 1].astype(float)
    x0, x1, y0, y1 = ia - 0.5, ia + 0.5, ib - 0.5, ib + 0.5
    near = np.where(ia == 0, 0.0, np.hypot(x0, np.maximum(y0, 0.0)))
    far = np.hypot(x1, y1)
    lo = np.searchsorted(b_edge, near, side="right")  # the first interval with b_edge > near
    hi = np.maximum(np.searchsorted(a_edge, far, side="left"), lo)  # past the last one with a_edge < far
    return x0, x1, y0, y1, lo, hi


def annulus_pixel_weights(annulus_edges_px: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``W`` (n_unique_pixels, n_annuli) with ``E_p = sum_k W[p, k] I_k``.

    ``annulus_edges_px``: (n_annuli + 1,) increasing radii in pixel units, starting at 0.
    ``I_k`` is intensity per pixel area on annulus k. Returns ``(W, index)`` where ``index``
    maps the K x K window to the unique pixels (see :func:`octant_pixels`).
    """
    offsets, index = octant_pixels(window)
    a = offsets[:, 0:1].astype(float)
    b = offsets[:, 1:2].astype(float)
    rho = np.asarray(annulus_edges_px, dtype=float)[None, :]
    area = disk_rectangle_area(rho, a - 0.5, a + 0.5, b - 0.5, b + 0.5)
    return np.diff(area, axis=1), index


def periodic_pixel_weights(
    centres_cells: np.ndarray, n_samples: int, max_frequency: int, pixel_cells: float
) -> np.ndarray:
    """Weights ``W`` (n_pixels, n_samples) with ``E_i = sum_n W[i, n] I_n``: the exact integral
    over the pixel ``[t_i - p/2, t_i + p/2]`` of the trigonometric polynomial of period ``N`` whose
    samples at ``t = n`` (n = 0..N-1) are ``I_n``, provided it has no frequency above ``max_frequency``
    (cycles per period; ``N >= 2 max_frequency + 1``).

    With ``I(t) = sum_k c_k exp(2 pi i k t / N)`` and ``c_k = (1/N) sum_n I_n exp(-2 pi i k n / N)``,

        int_{t_i - p/2}^{t_i + p/2} I(t) dt = sum_{|k| <= max_frequency} c_k p sinc(k p / N) exp(2 pi i k t_i / N),

    so ``W[i, n] = (p / N) sum_{|k| <= max_frequency} sinc(k p / N) cos(2 pi k (t_i - n) / N)``
    (sinc(x) = sin(pi x) / (pi x)): the pixel's box filter is a sinc factor on the Fourier
    coefficients. ``centres_cells`` ``t_i`` and ``pixel_cells`` ``p`` are in sample spacings.
    Each row is one FFT of length ``N``.
    """
    n = int(n_samples)
    kmax = int(max_frequency)
    if n < 2 * kmax + 1:
        raise ValueError(f"{n} samples cannot represent frequencies up to {kmax}")
    t = np.asarray(centres_cells, dtype=float)[:, None]
    k = np.fft.fftfreq(n, 1.0 / n)[None, :]  # 0, 1, ..., -1 (integers)
    factor = np.where(np.abs(k) <= kmax, pixel_cells * np.sinc(k * pixel_cells / n), 0.0)
    coefficients = factor * np.exp(2j * np.pi * k * t / n)  # (n_pixels, N)
    return np.fft.fft(coefficients, axis=1).real / n
