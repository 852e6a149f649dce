"""Box-constrained least-squares compensation with the PSF known (method ``lens+cls``).

The projector can only emit light in [0, 1], so instead of inverting the blur and clipping
afterwards (Wiener), solve the constrained problem directly, per colour channel:

    minimize   f(x) = ½ ‖A x − I‖²     subject to   0 ≤ x ≤ 1,
    A x = p ⊛ x + h · mean(x),          h = 1 − Σp

(``⊛`` the zero-padded linear convolution with output of the same size, i.e. the projection
of :func:`edofproj.imaging.project` for inputs already in [0, 1]). The gradient is
``∇f(x) = Aᵀ(A x − I)`` with the adjoint ``Aᵀ r = p̃ ⊛ r + h · mean(r)`` (``p̃`` the PSF
rotated by 180°: a correlation). Both use the project's FFT operator
(:mod:`edofproj.imaging.convolution`): the centred transfer function ``H`` on the grid where the
circular convolution equals the linear one on the cropped frame, and ``conj(H)`` for the adjoint.

**Step size.** ``∇f`` is Lipschitz with ``L = ‖A‖² ≤ (Σ|p| + h)²`` (Young's inequality for
the convolution, triangle inequality for the sum); for a non-negative PSF with haze
``L ≤ 1``. The solver uses the step ``1 / L`` with that bound per channel, so no line
search is needed.

**Iterations.** ``method="pgd"``: projected gradient ``x ← Π(x − ∇f(x)/L)``, ``Π`` the
clamp to [0, 1], monotone. ``method="fista"`` (default): monotone FISTA (MFISTA, Beck &
Teboulle 2009, "Fast gradient-based algorithms for constrained total variation image
denoising and deblurring"), accelerated with ``O(1/k²)`` convergence and, by its
``argmin`` rule, a non-increasing objective. Both start from ``x = clamp(I, 0, 1)`` and run
a fixed number of iterations (default 100).
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from ..errors import EdofprojError
from ..imaging.convolution import apply_transfer_function, fft_shape, optical_transfer_function

METHOD_NAME = "lens+cls"
SOLVERS = ("fista", "pgd")


class BlurHazeOperator:
    """The linear projection operator ``A x = p ⊛ x + h·mean(x)`` and its adjoint, by FFT.

    ``psf`` (C, K, K) or (1|B, C, K, K) for frames of ``height × width``. With ``haze=False``
    the operator is the convolution alone.
    """

    def __init__(self, psf: torch.Tensor, height: int, width: int, haze: bool = True):
        if psf.ndim == 3:
            psf = psf.unsqueeze(0)
        if psf.ndim != 4 or psf.shape[-1] != psf.shape[-2] or psf.shape[-1] % 2 == 0:
            raise EdofprojError(f"PSF must be (C,K,K) or (N,C,K,K) with K odd, got {tuple(psf.shape)}")
        if not torch.isfinite(psf).all():
            raise EdofprojError("the PSF contains NaN or infinite values")
        k = psf.shape[-1]
        self.height, self.width = int(height), int(width)
        self.grid = fft_shape((self.height, self.width), (k, k))
        self.otf = optical_transfer_function(psf, self.grid)
        mass = psf.sum(dim=(-1, -2), keepdim=True)
        self.haze_fraction = (1.0 - mass) if haze else torch.zeros_like(mass)
        #: Lipschitz bound of the gradient per (sample, channel): (Σ|p| + |h|)².
        self.lipschitz = (psf.abs().sum(dim=(-1, -2), keepdim=True) + self.haze_fraction.abs()) ** 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``A x = p ⊛ x + h · mean(x)``."""
        return apply_transfer_function(x, self.otf, self.grid) + self.haze_fraction * x.mean(dim=(-1, -2), keepdim=True)

    def adjoint(self, r: torch.Tensor) -> torch.Tensor:
        """``Aᵀ r = p̃ ⊛ r + h · mean(r)`` (correlation with the PSF)."""
        return apply_transfer_function(r, self.otf.conj(), self.grid) + self.haze_fraction * r.mean(
            dim=(-1, -2), keepdim=True
        )

    __call__ = forward


def _objective(residual: torch.Tensor) -> torch.Tensor:
    """½‖r‖² per image (summed over channels and pixels)."""
    return 0.5 * (residual**2).flatten(1).sum(dim=1)


def box_constrained_deconvolution(
    target: torch.Tensor,
    psf: torch.Tensor,
    iterations: int = 100,
    method: str = "fista",
    haze: bool = True,
    return_objective: bool = False,
    callback: Callable[[int, torch.Tensor], None] | None = None,
):
    """The projector input ``x ∈ [0,1]`` minimizing ``½‖p ⊛ x + h·mean(x) − I‖²``.

    ``target`` (B, C, H, W) in [0, 1]; ``psf`` (C|1, K, K) or (1|B, C|1, K, K). Returns ``x``
    (B, C, H, W), or ``(x, objective)`` with ``objective`` a tensor ``(iterations + 1, B)``
    of ``f`` at the start and after each iteration when ``return_objective``.
    ``callback(k, x)`` is called with the iterate after each iteration ``k = 1 … iterations``.
    """
    if method not in SOLVERS:
        raise EdofprojError(f"unknown constrained solver '{method}' (known: {', '.join(SOLVERS)})")
    if int(iterations) < 0:
        raise EdofprojError(f"iterations={iterations} must be >= 0")
    if target.ndim != 4:
        raise EdofprojError(f"target must be (B, C, H, W), got {tuple(target.shape)}")
    psf = psf.to(target.device, target.dtype)
    if psf.shape[-3] not in (1, target.shape[1]) or (psf.ndim == 4 and psf.shape[0] not in (1, target.shape[0])):
        raise EdofprojError(f"PSF {tuple(psf.shape)} does not match target {tuple(target.shape)}")
    with torch.no_grad():
        op = BlurHazeOperator(psf, target.shape[-2], target.shape[-1], haze=haze)
        return box_least_squares(
            target,
            op.forward,
            op.adjoint,
            1.0 / op.lipschitz.clamp_min(1e-12),
            iterations,
            method,
            return_objective=return_objective,
            callback=callback,
        )


def box_least_squares(
    target: torch.Tensor,
    forward: Callable[[torch.Tensor], torch.Tensor],
    adjoint: Callable[[torch.Tensor], torch.Tensor],
    step,
    iterations: int = 100,
    method: str = "fista",
    start: torch.Tensor | None = None,
    return_objective: bool = False,
    callback: Callable[[int, torch.Tensor], None] | None = None,
):
    """The solver of the module docstring for any linear operator: ``x in [0, 1]`` minimizing
    ``1/2 ||A x - I||^2`` with ``A = forward``, ``A^T = adjoint`` and the step ``1 / L`` (``step`` a
    number or a tensor broadcasting against ``(B, C, 1, 1)``, ``L >= ||A||^2`` per channel).
    ``start``: the first iterate (default ``clamp(I, 0, 1)``; clamped). Returns as
    :func:`box_constrained_deconvolution`."""
    if method not in SOLVERS:
        raise EdofprojError(f"unknown constrained solver '{method}' (known: {', '.join(SOLVERS)})")
    if int(iterations) < 0:
        raise EdofprojError(f"iterations={iterations} must be >= 0")
    with torch.no_grad():
        # A is linear, so A y of FISTA's extrapolated point y = x + a (z - x) + b (x - x_prev) is the same
        # combination of A z, A x and A x_prev, all at hand: each iteration applies A once and Aᵀ once.
        def gradient_step(y: torch.Tensor, a_y: torch.Tensor) -> torch.Tensor:
            return (y - step * adjoint(a_y - target)).clamp_(0.0, 1.0)

        x = (target if start is None else start).clamp(0.0, 1.0)
        a_x = forward(x)
        f_x = _objective(a_x - target)
        history = [f_x]
        if method == "pgd":
            for _ in range(int(iterations)):
                x = gradient_step(x, a_x)
                a_x = forward(x)
                f_x = _objective(a_x - target)
                history.append(f_x)
                if callback is not None:
                    callback(len(history) - 1, x)
        else:  # monotone FISTA
            y, a_y, t = x, a_x, 1.0
            for _ in range(int(iterations)):
                z = gradient_step(y, a_y)
                a_z = forward(z)
                f_z = _objective(a_z - target)
                better = (f_z <= f_x).view(-1, 1, 1, 1)
                x_prev, x = x, torch.where(better, z, x)
                a_x_prev, a_x = a_x, torch.where(better, a_z, a_x)
                f_x = torch.minimum(f_z, f_x)
                t_next = (1.0 + math.sqrt(1.0 + 4.0 * t * t)) / 2.0
                momentum, inertia = t / t_next, (t - 1.0) / t_next
                y = x + momentum * (z - x) + inertia * (x - x_prev)
                a_y = a_x + momentum * (a_z - a_x) + inertia * (a_x - a_x_prev)
                t = t_next
                history.append(f_x)
                if callback is not None:
                    callback(len(history) - 1, x)
    if return_objective:
        return x, torch.stack(history)
    return x
