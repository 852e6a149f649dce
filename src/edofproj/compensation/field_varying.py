"""Compensation of a blur that varies across the image (:class:`edofproj.imaging.field_varying.FieldVaryingBlur`):
a field-varying Wiener filter and box-constrained least squares.

**Wiener, field-varying.** Each node ``g`` of the blur's kernel grid gets the Wiener filter of its own
kernel (:mod:`.wiener`: ``G_g = conj(H_g) / (|H_g|^2 + NSR)``, ``H_g`` with the haze DC gain), and the
outputs are blended with the same tent weights ``w_g`` that interpolate the blur's kernels,

    x = clamp( sum_g w_g . (g_g (*) t), 0, 1 ),

the *output* (transpose) form: each pixel is restored by the Wiener filter of its own interpolated
neighbourhood, and since ``sum_g w_g = 1`` there are no seams between nodes; with one kernel
everywhere it is :func:`.wiener.wiener_deconvolve`. The target is reflected at its borders and
filtered on the same frame as the spatially invariant filter (:func:`.wiener.padding_for`). The
kernels ``g_g`` are computed on a ``Q x Q`` periodic frame (``Q = 4 K + 1``, at least 65, at most the
filtering frame), and, as in
the blur, written in a low-rank basis (:func:`edofproj.imaging.field_varying.low_rank_kernels`):
``M`` inverse transforms of the target's one spectrum, whatever the number of nodes. The
difference from the filter on the whole frame is the Wiener kernel's tail beyond ``Q / 2`` pixels.

**Constrained least squares.** :func:`field_varying_cls` minimizes ``1/2 ||A x - t||^2`` subject to
``0 <= x <= 1`` with the exact operator and its adjoint, from a start (default the target clamped to
the box) for a fixed number of iterations, each one application of ``A`` and one of ``A^T``: by
projected quasi-Newton steps with an exact line search (:func:`.box_quasi_newton.box_quasi_newton`,
``"lbfgs"``, the default) or by the project's first-order solver (:func:`.constrained.box_least_squares`:
``"fista"``, monotone FISTA, or ``"pgd"``, step ``1 / L`` with ``L`` Schur's bound on ``||A||^2``). At
equal cost the quasi-Newton steps reach the lower objective (on a kernel map of a textured scene, 20 of
them lower than 40 FISTA steps); it reports the objective at every iteration, so convergence is
visible, not assumed.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.convolution import optical_transfer_function
from ..imaging.field_varying import FieldVaryingBlur, hat_weights, low_rank_kernels
from .box_quasi_newton import box_quasi_newton
from .constrained import SOLVERS, box_least_squares
from .wiener import checked_nsr, padding_for

DEFAULT_CLS_ITERATIONS = 20
"""Iterations of :func:`field_varying_cls` by default."""
CLS_METHODS = (*SOLVERS, "lbfgs")
"""Solvers of :func:`field_varying_cls`: monotone FISTA, projected gradient, projected quasi-Newton."""
DEFAULT_CLS_SOLVER = "lbfgs"
"""The solver of :func:`field_varying_cls` by default: the lowest objective for the iterations given."""
WIENER_NODE_SPACING_PX = 48
"""Least spacing (px) of the nodes that get their own Wiener filter (the blur's nodes, thinned)."""


def _thinned(centres: np.ndarray, spacing_px: float) -> np.ndarray:
    """Indices of ``centres`` at least ``spacing_px`` apart, the first and the last kept."""
    keep = [0]
    for i in range(1, len(centres)):
        if centres[i] - centres[keep[-1]] >= spacing_px:
            keep.append(i)
    if keep[-1] != len(centres) - 1:
        if len(keep) > 1:
            keep[-1] = len(centres) - 1  # the last node replaces the last kept one, closer than the spacing to it
        else:
            keep.append(len(centres) - 1)
    return np.array(keep)


class FieldVaryingWiener:
    """The field-varying Wiener filter of the module docstring for the blur ``op`` and one ``nsr``.

    ``node_spacing_px``: the blur's nodes are thinned to at least this spacing (default
    ``WIENER_NODE_SPACING_PX``; 0 keeps them all); ``rank_tolerance`` as in
    :class:`~edofproj.imaging.field_varying.FieldVaryingBlur` for the Wiener kernels.
    ``frame_px``: ``Q`` or ``(Qy, Qx)`` (default ``max(4 K + 1, 65)``, at most the filtering frame; the
    filtering frame itself gives exactly the invariant filter's kernels). ``w(target (B, C, H, W))`` -> ``x`` in
    ``[0, 1]``, the filters cached per dtype and device.
    """

    def __init__(
        self,
        op: FieldVaryingBlur,
        nsr: float,
        node_spacing_px: float = WIENER_NODE_SPACING_PX,
        rank_tolerance: float = 1e-2,
        haze: bool = True,
        pad: bool = True,
        frame_px: int | tuple[int, int] | None = None,
    ):
        self.nsr = checked_nsr(nsr)
        self.height, self.width = op.height, op.width
        rows, cols = _thinned(op.centres_y_px, node_spacing_px), _thinned(op.centres_x_px, node_spacing_px)
        kernels = op.kernels[rows][:, cols].to(torch.float64)  # (Gy, Gx, C|1, K, K)
        gy, gx, channels, k = kernels.shape[0], kernels.shape[1], kernels.shape[2], kernels.shape[-1]
        self.pads = padding_for(self.height, self.width, k, pad)  # the frame of the invariant filter
        self.frame = (self.height + self.pads[0] + self.pads[1], self.width + self.pads[2] + self.pads[3])
        if frame_px is None:
            q = (min(max(4 * k + 1, 65), self.frame[0]), min(max(4 * k + 1, 65), self.frame[1]))
        else:
            q = (int(frame_px), int(frame_px)) if isinstance(frame_px, int) else (int(frame_px[0]), int(frame_px[1]))
        if not (k <= q[0] <= self.frame[0] and k <= q[1] <= self.frame[1]):
            raise EdofprojError(
                f"the Wiener kernels' frame {q[0]}x{q[1]} px must hold the blur's {k} px and fit in the "
                f"filtering frame {self.frame[0]}x{self.frame[1]}"
            )
        otf = optical_transfer_function(kernels, q, haze=haze)
        filters = otf.conj() / (otf.abs() ** 2 + self.nsr)
        # the spatial Wiener kernels on the q frame, centre at pixel (q//2): the frame's inverse transform
        spatial = torch.fft.fftshift(torch.fft.irfft2(filters, s=q), dim=(-2, -1))
        wy = torch.as_tensor(hat_weights(op.centres_y_px[rows], self.height))
        wx = torch.as_tensor(hat_weights(op.centres_x_px[cols], self.width))
        bases, maps = [], []
        for c in range(channels):
            # Wiener kernels need more terms than the blur's (about 46 for a PSF map's): the larger sketch at once
            basis, coefficients = low_rank_kernels(spatial[:, :, c].reshape(gy * gx, *q), rank_tolerance, (64,))
            bases.append(basis)
            maps.append(torch.einsum("iy,ijm,jx->myx", wy, coefficients.reshape(gy, gx, -1), wx))
        rank = max(b.shape[0] for b in bases)
        self.basis = torch.stack([_pad_first(b, rank) for b in bases])  # (C|1, M, q, q)
        self.coefficients = torch.stack([_pad_first(m, rank) for m in maps])  # (C|1, M, H, W)
        self._cache: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}

    @property
    def rank(self) -> int:
        """Basis Wiener kernels (inverse transforms) per image."""
        return int(self.basis.shape[1])

    def __call__(self, target: torch.Tensor) -> torch.Tensor:
        if target.ndim != 4 or tuple(target.shape[-2:]) != (self.height, self.width):
            raise EdofprojError(
                f"the filter is set up for (B, C, {self.height}, {self.width}) images, got {tuple(target.shape)}"
            )
        if self.basis.shape[0] not in (1, target.shape[1]):
            raise EdofprojError(f"{self.basis.shape[0]}-channel Wiener filters for a {target.shape[1]}-channel image")
        key = (target.dtype, target.device)
        if key not in self._cache:
            otf = optical_transfer_function(self.basis.to(target.device, target.dtype), self.frame)
            self._cache[key] = (self.coefficients.to(target.device, target.dtype), otf)
        maps, otf = self._cache[key]
        top, bottom, left, right = self.pads
        padded = (
            torch.nn.functional.pad(target, (left, right, top, bottom), mode="reflect") if any(self.pads) else target
        )
        spectrum = torch.fft.rfft2(padded)
        out = torch.zeros_like(target)
        for m in range(self.rank):
            restored = torch.fft.irfft2(spectrum * otf[:, m], s=self.frame)
            out.addcmul_(restored[..., top : top + self.height, left : left + self.width], maps[:, m])
        return out.clamp_(0.0, 1.0)


def _pad_first(tensor: torch.Tensor, rank: int) -> torch.Tensor:
    if tensor.shape[0] == rank:
        return tensor
    return torch.cat([tensor, tensor.new_zeros((rank - tensor.shape[0],) + tuple(tensor.shape[1:]))])


def field_varying_cls(
    target: torch.Tensor,
    op: FieldVaryingBlur,
    iterations: int = DEFAULT_CLS_ITERATIONS,
    start: torch.Tensor | None = None,
    method: str = DEFAULT_CLS_SOLVER,
    return_objective: bool = False,
):
    """``argmin_{0 <= x <= 1} 1/2 ||A x - t||^2`` (module docstring) for ``target (B, C, H, W)``;
    ``start`` the first iterate (default ``clamp(t, 0, 1)``), ``method`` one of :data:`CLS_METHODS`.
    Returns ``x``, or ``(x, objective (iterations + 1, B))`` with ``return_objective``."""
    if target.ndim != 4:
        raise EdofprojError(f"target must be (B, C, H, W), got {tuple(target.shape)}")
    if method not in CLS_METHODS:
        raise EdofprojError(f"unknown constrained solver '{method}' (known: {', '.join(CLS_METHODS)})")
    if method == "lbfgs":
        x, objective = box_quasi_newton(target, op.forward, op.adjoint, iterations, start)
        return (x, objective) if return_objective else x
    lipschitz = op.norm_bound().to(target.device, target.dtype) ** 2 * 1.000001
    step = (1.0 / lipschitz.clamp_min(1e-12)).view(1, -1, 1, 1)
    return box_least_squares(target, op.forward, op.adjoint, step, iterations, method, start, return_objective)
