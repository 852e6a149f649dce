"""The 2-D real DFT written as matrix products: the form an FFT takes in an ONNX export.

ONNX Runtime's ``DFT`` operator (CPU) runs every length that is not a power of two by Bluestein's
algorithm (three power-of-two transforms of about twice the length) in scalar code: the FFT
convolutions of the exported networks (the linear base filter, the radial Fourier filter, the
display guard's projections) took 44-69 % of ONNX Runtime's time per 600x800 frame
(docs/experiments/2026-11-27-onnx-speed.md). Here the same transforms are float32 matrix products,
which ONNX Runtime runs with its GEMM kernels (``MatMul``).

**One axis, four steps (Cooley-Tukey).** For a length ``N = N1 N2`` (``N1`` the largest divisor
``<= sqrt(N)``, :func:`factor_length`), with ``n = N2 a + b`` and ``k = c + N1 d``
(``a, c < N1``; ``b, d < N2``; ``w_M = exp(-+2 pi i / M)``, ``+`` for the inverse):

    X[c + N1 d] = sum_b  w_N2^(b d) w_N^(b c)  sum_a  x[N2 a + b] w_N1^(a c)

Stage 1 is one matrix product from the left, the ``N1``-point DFT over ``a`` for every ``b``;
stage 2 is, for each ``c``, the ``N2``-point DFT over ``b`` with the *twiddle* ``w_N^(b c)`` folded
into its matrix (a batch of ``N1`` matrices). That is ``N (N1 + N2)`` complex multiply-adds instead
of ``N^2`` (a prime ``N`` is one dense product, ``N1 = 1``). The transform runs along the rows
(axis -2) of ``(..., N, W)`` tensors, so both products have the long ``W`` axis as their columns.
Complex values are real tensors with the real and imaginary parts stacked on axis -3
(``(..., 2, N, W)``), and a complex product is one real product with the block matrix
``[[Re, -Im], [Im, Re]]``. Only the output rows asked for are computed (the crop after an inverse
transform costs nothing), and only the real part of a real output.

**Two axes, transposed half spectrum.** :func:`rfft2` transforms a real ``(..., H, W)`` image,
zero-padded to ``Gh x Gw``, along the rows first, keeping the ``Gh // 2 + 1`` non-negative row
frequencies (the image is real), transposes, and transforms along the columns: the spectrum is
``(..., 2, Gw, Gh // 2 + 1)``, indexed ``[kx, ky]``, with ``ky`` halved where
:func:`torch.fft.rfft2` halves ``kx`` (one transpose each way instead of four). Transfer functions
multiply it in that layout (:func:`half_spectrum_frequencies`, :func:`complex_multiply`).
:func:`irfft2` inverts it (the missing row frequencies are the conjugates of the kept ones) and
returns only the requested rows and columns of the ``Gh x Gw`` periodic result.

The matrices are computed in float64 and cast to the image's dtype; in float32 the round trip of
a 600x800 frame is exact to about 1e-6 of its range.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch


def factor_length(n: int) -> tuple[int, int]:
    """``(N1, N2)`` with ``N1 N2 = n`` and ``N1`` the largest divisor of ``n`` not above ``sqrt(n)``."""
    n = int(n)
    if n < 1:
        raise ValueError(f"DFT length {n} must be positive")
    first = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    return first, n // first


def _phase(rows: np.ndarray, cols: np.ndarray, n: int, inverse: bool) -> np.ndarray:
    """``-+2 pi (r c mod n) / n`` for every pair (exact integer products before the division)."""
    product = np.mod(rows[:, None].astype(np.int64) * cols[None, :].astype(np.int64), n)
    return (2 * np.pi / n) * product * (1.0 if inverse else -1.0)


def _complex_block(re: np.ndarray, im: np.ndarray, real_input: bool, real_output: bool) -> np.ndarray:
    """The real matrix of ``(re + i im) @`` on stacked ``[x_re; x_im]`` (rows ``[re; im]`` of the
    product; a real input has no ``x_im`` columns, a real output no ``im`` rows)."""
    top = re if real_input else np.concatenate([re, -im], axis=-1)
    if real_output:
        return top
    bottom = im if real_input else np.concatenate([im, re], axis=-1)
    return np.concatenate([top, bottom], axis=-2)


@lru_cache(maxsize=64)
def _stage_matrices(
    n: int, first: int, last: int, inverse: bool, real_input: bool, real_output: bool
) -> tuple[np.ndarray, np.ndarray]:
    """``(M1, G)`` of :func:`dft_rows`, float64.

    ``M1`` ``(2 N1, [2] N1)``: rows ``(c, part)``, columns ``([part,] a)``, the ``N1``-point DFT.
    ``G`` ``(N1, [2] D, 2 N2)``: for each ``c``, rows ``([part,] d)`` for ``first <= d < last``, columns
    ``(part, b)``, the ``N2``-point DFT with the twiddle ``w_N^(b c)`` folded in (and ``1 / N`` for
    the inverse)."""
    n1, n2 = factor_length(n)
    a, b = np.arange(n1), np.arange(n2)
    phase1 = _phase(a, a, n1, inverse)  # [c, a]
    m1 = _complex_block(np.cos(phase1), np.sin(phase1), real_input, False)  # rows (part, c)
    # reorder the rows from (part, c) to (c, part)
    m1 = m1.reshape(2, n1, -1).transpose(1, 0, 2).reshape(2 * n1, -1)
    d = np.arange(first, last)
    scale = 1.0 / n if inverse else 1.0
    blocks = []
    for c in range(n1):
        phase = _phase(d, b, n2, inverse) + _phase(np.array([c]), b, n, inverse)  # [d, b]
        blocks.append(_complex_block(scale * np.cos(phase), scale * np.sin(phase), False, real_output))
    return m1, np.stack(blocks)


def _constant(values: np.ndarray, like: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(values)).to(dtype=like.dtype, device=like.device)


def dft_rows(
    x: torch.Tensor,
    rows: tuple[int, int] | None = None,
    inverse: bool = False,
    real_input: bool = False,
    real_output: bool = False,
    transpose: bool = False,
) -> torch.Tensor:
    """Rows ``rows = (start, stop)`` (default: all) of the DFT along the rows of ``x``.

    ``x``: complex ``(..., 2, N, W)`` (real and imaginary parts stacked on axis -3), or real
    ``(..., N, W)`` with ``real_input``. Returns ``(..., 2, stop - start, W)``, only the real part
    ``(..., stop - start, W)`` with ``real_output``, and with ``transpose`` the last two axes
    swapped (``(..., 2, W, stop - start)``: the next transform's rows are this one's columns). The
    inverse includes the ``1 / N``. Two matrix products (module docstring)."""
    n, width = x.shape[-2], x.shape[-1]
    lead = x.shape[:-2] if real_input else x.shape[:-3]
    start, stop = rows if rows is not None else (0, n)
    n1, n2 = factor_length(n)
    first, last = start // n1, -(-stop // n1)  # the d that hold rows start..stop-1 (k = c + N1 d)
    m1, g = (_constant(m, x) for m in _stage_matrices(n, first, last, inverse, real_input, real_output))
    # stage 1: the N1-point DFT over a for every b: (..., [2] N1, N2 W) -> (..., N1 2, N2 W)
    y = m1 @ x.reshape(*lead, -1, n2 * width)
    # stage 2: per c, twiddle and N2-point DFT over b: (..., N1, 2 N2, W) -> (..., N1, [2] D, W)
    parts = 1 if real_output else 2
    z = (g @ y.reshape(*lead, n1, 2 * n2, width)).reshape(*lead, n1, parts, last - first, width)
    # rows k = c + N1 d, in order
    count = len(lead)
    z = z.permute(*range(count), count + 1, count + 2, count, count + 3).reshape(*lead, parts, -1, width)
    offset = first * n1
    z = z[..., start - offset : stop - offset, :]
    if transpose:
        z = z.transpose(-1, -2)
    return z.squeeze(-3) if real_output else z


def rfft2(image: torch.Tensor, grid_hw: tuple[int, int]) -> torch.Tensor:
    """Spectrum ``(..., 2, Gw, Gh // 2 + 1)`` (transposed half layout, module docstring) of ``image
    (..., H, W)`` zero-padded to ``grid_hw = (Gh, Gw)``."""
    gh, gw = int(grid_hw[0]), int(grid_hw[1])
    height, width = image.shape[-2:]
    if (height, width) != (gh, gw):
        image = torch.nn.functional.pad(image, (0, gw - width, 0, gh - height))
    half = dft_rows(image, (0, gh // 2 + 1), real_input=True, transpose=True)  # (..., 2, Gw, Gh // 2 + 1)
    return dft_rows(half)


def irfft2(
    spectrum: torch.Tensor,
    grid_hw: tuple[int, int],
    rows: tuple[int, int] | None = None,
    cols: tuple[int, int] | None = None,
) -> torch.Tensor:
    """The real ``Gh x Gw`` periodic signal of a transposed half ``spectrum`` (:func:`rfft2`), only
    its rows ``rows = (start, stop)`` and columns ``cols`` (default: all)."""
    gh, gw = int(grid_hw[0]), int(grid_hw[1])
    half = dft_rows(spectrum, cols or (0, gw), inverse=True, transpose=True)  # (..., 2, Gh // 2 + 1, columns)
    # row frequencies Gh // 2 + 1 .. Gh - 1: the conjugates of Gh - 1 .. 1 (the signal is real)
    conjugate = torch.tensor([[[1.0]], [[-1.0]]], dtype=half.dtype, device=half.device)
    full = torch.cat([half, (half[..., 1 : (gh + 1) // 2, :] * conjugate).flip(-2)], dim=-2)
    return dft_rows(full, rows or (0, gh), inverse=True, real_output=True)


def complex_multiply(spectrum: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """``spectrum * factor`` for complex values stacked on axis -3 (``(..., 2, M, N)``, broadcasting)."""
    re, im = spectrum.unbind(-3)
    factor_re, factor_im = factor.unbind(-3)
    return torch.stack([re * factor_re - im * factor_im, re * factor_im + im * factor_re], dim=-3)


def half_spectrum_frequencies(grid_hw: tuple[int, int], device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(fx, fy)`` in cycles per pixel on the transposed half layout of a ``Gh x Gw`` grid:
    ``fx (Gw, 1)`` as :func:`torch.fft.fftfreq`, ``fy (1, Gh // 2 + 1)`` as :func:`torch.fft.rfftfreq`."""
    gh, gw = int(grid_hw[0]), int(grid_hw[1])
    return torch.fft.fftfreq(gw, device=device)[:, None], torch.fft.rfftfreq(gh, device=device)[None, :]
