"""Li et al.'s (IEEE TII 2020) scoring protocol: a compensation blurred in simulation, scored against the original.

Their ``metrics_for_vgroove.m`` / ``metrics_for_textured.m`` (with ``cal_metrics_step3.m``) score a
compensation image ``c`` for an original ``t`` (8-bit RGB projector images, values ``0..255``):

1. blur both with the measured blur ``A`` (one kernel per pixel and colour), ``b_t = q(A t)``
   ("normal projection") and ``b_c = q(A c)``, where ``q`` is MATLAB's ``uint8()``: round half away
   from zero, saturate to ``[0, 255]`` (:func:`to_uint8`);
2. cut one fixed crop out of ``t``, ``b_t`` and ``b_c`` (:class:`Crop`), as ``double`` in ``0..255``;
3. score ``b_t`` and ``b_c`` against ``t`` over the crop's three channels together:

   * SSIM: MATLAB's ``ssim(A, ref)`` of the ``H x W x 3`` arrays (:func:`matlab_ssim`);
   * PSNR ``10 log10(P^2 / MSE)`` with ``MSE`` the mean over all values and the peak
     ``P = min(max b_t, max t)`` -- taken from the *normal projection* for every row;
   * RMSE ``sqrt(MSE)`` in 8-bit counts.

**MATLAB's SSIM on double arrays** (Image Processing Toolbox, R2018b, the release their README
names). An ``H x W x 3`` array is a 3-D *volume* to ``ssim``, not an RGB image: its local statistics
are weighted by a 3-D Gaussian (``imgaussfilt3``, sigma 1.5 on all three axes, ``2 ceil(3 sigma) + 1
= 11`` taps each, ``'replicate'`` padding, output the input's size), so the channels mix (each one
weighted with its neighbours padded by replication along the colour axis). The dynamic range of a
``double`` array is 1 (``diff(getrangefromclass)``), so ``C1 = (0.01 * 1)^2`` and ``C2 = (0.03 *
1)^2`` on data in ``0..255``: the constants are negligible. With ``C3 = C2 / 2`` and unit exponents,

    SSIM map = (2 mu_x mu_y + C1) (2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1) (s_x^2 + s_y^2 + C2)),

``mu`` the weighted means, ``s^2 = E_w[x^2] - mu^2`` (not the sample covariance), and the score is
the mean of the map over every element of the volume (no border cropped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage

from ..errors import EdofprojError
from ..fileio import read_arrays

SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
MATLAB_DOUBLE_RANGE = 1.0
"""``diff(getrangefromclass(x))`` for a ``double`` array: MATLAB's default SSIM dynamic range here."""


def matlab_gaussian_taps(sigma: float = SSIM_SIGMA) -> np.ndarray:
    """``(2 ceil(3 sigma) + 1,)``: ``exp(-x^2 / (2 sigma^2))`` at integer ``x``, summing to 1."""
    radius = int(math.ceil(3.0 * sigma))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    taps = np.exp(-(x**2) / (2.0 * sigma**2))
    return taps / taps.sum()


def _gaussian_filter(image: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """The separable Gaussian along every axis, replicate padding, same size (``imgaussfilt[3]``)."""
    out = image
    for axis in range(image.ndim):
        out = ndimage.correlate1d(out, taps, axis=axis, mode="nearest")
    return out


def matlab_ssim(
    image: np.ndarray, reference: np.ndarray, dynamic_range: float = MATLAB_DOUBLE_RANGE, sigma: float = SSIM_SIGMA
) -> tuple[float, np.ndarray]:
    """MATLAB's ``[ssimval, ssimmap] = ssim(image, reference)`` of two ``double`` arrays of one shape,
    2-D (an image) or 3-D (a volume: ``H x W x 3`` RGB is one) (module docstring)."""
    x = np.asarray(image, dtype=np.float64)
    y = np.asarray(reference, dtype=np.float64)
    if x.shape != y.shape or x.ndim not in (2, 3):
        raise EdofprojError(f"SSIM needs two 2-D or 3-D arrays of one shape, got {x.shape} and {y.shape}")
    taps = matlab_gaussian_taps(sigma)
    c1, c2 = (SSIM_K1 * dynamic_range) ** 2, (SSIM_K2 * dynamic_range) ** 2
    mu_x, mu_y = _gaussian_filter(x, taps), _gaussian_filter(y, taps)
    mu_xy, mu_x2, mu_y2 = mu_x * mu_y, mu_x * mu_x, mu_y * mu_y
    s_x2 = _gaussian_filter(x * x, taps) - mu_x2
    s_y2 = _gaussian_filter(y * y, taps) - mu_y2
    s_xy = _gaussian_filter(x * y, taps) - mu_xy
    ssim_map = ((2 * mu_xy + c1) * (2 * s_xy + c2)) / ((mu_x2 + mu_y2 + c1) * (s_x2 + s_y2 + c2))
    return float(ssim_map.mean()), ssim_map


def to_uint8(values: np.ndarray) -> np.ndarray:
    """MATLAB's ``uint8(x)`` of a ``double`` array, kept as float64: round half away from zero, saturate
    to ``[0, 255]``, NaN to 0."""
    values = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0)
    return np.clip(np.sign(values) * np.floor(np.abs(values) + 0.5), 0.0, 255.0)


@dataclass(frozen=True)
class Crop:
    """Rows ``y0 <= y < y1``, columns ``x0 <= x < x1`` (0-based, end excluded: Python's slices). MATLAB's
    1-based inclusive ``top_left = [r0, c0]``, ``bottom_right = [r1, c1]`` is ``Crop(r0 - 1, r1, c0 - 1, c1)``."""

    y0: int
    y1: int
    x0: int
    x1: int

    @classmethod
    def parse(cls, text: str, option: str = "--crop") -> "Crop":
        """``"y0,y1,x0,x1"`` (integers)."""
        try:
            values = [int(v) for v in str(text).split(",")]
        except ValueError:
            values = []
        if len(values) != 4:
            raise EdofprojError(f"{option} '{text}' must be four integers y0,y1,x0,x1 (0-based, end excluded)")
        return cls(*values)

    @classmethod
    def matlab(cls, top_left: Sequence[int], bottom_right: Sequence[int]) -> "Crop":
        """From MATLAB's 1-based inclusive corners ``[row, column]``."""
        return cls(int(top_left[0]) - 1, int(bottom_right[0]), int(top_left[1]) - 1, int(bottom_right[1]))

    def check(self, hw: tuple[int, int], option: str = "--crop") -> "Crop":
        H, W = hw
        if not (0 <= self.y0 < self.y1 <= H and 0 <= self.x0 < self.x1 <= W):
            raise EdofprojError(
                f"{option} {self.y0},{self.y1},{self.x0},{self.x1} is not inside the {W}x{H} image "
                "(0 <= y0 < y1 <= height, 0 <= x0 < x1 <= width)"
            )
        if self.y1 - self.y0 < 2 or self.x1 - self.x0 < 2:
            raise EdofprojError(f"{option} leaves fewer than 2x2 pixels to score")
        return self

    def cut(self, image: np.ndarray) -> np.ndarray:
        return image[self.y0 : self.y1, self.x0 : self.x1]


@dataclass
class ProtocolScore:
    """One row of the protocol's table: the simulated result of ``name`` against the original."""

    name: str
    ssim: float
    psnr_db: float
    rmse: float


Blur = Callable[[np.ndarray], np.ndarray]
"""``(H, W, 3)`` float64 ``0..255`` -> the same, blurred (before the protocol rounds it)."""


def score_compensations(
    original: np.ndarray,
    compensations: Sequence[tuple[str, np.ndarray]],
    blur: Blur,
    crop: Crop | None = None,
    normal_name: str = "normal projection",
) -> list[ProtocolScore]:
    """The protocol (module docstring) for ``original`` ``(H, W, 3)`` and each named compensation (the
    same shape), all in 8-bit counts ``0..255``: the first row is the original itself blurred (the
    normal projection), then one row per compensation, in order."""
    original = np.asarray(original, dtype=np.float64)
    if original.ndim != 3 or original.shape[-1] != 3:
        raise EdofprojError(f"the original must be an RGB image, got shape {original.shape}")
    crop = (crop or Crop(0, original.shape[0], 0, original.shape[1])).check(original.shape[:2])
    reference = crop.cut(original)
    normal = crop.cut(to_uint8(blur(original)))
    peak = min(float(normal.max()), float(reference.max()))
    rows = [_row(normal_name, normal, reference, peak)]
    for name, image in compensations:
        image = np.asarray(image, dtype=np.float64)
        if image.shape != original.shape:
            raise EdofprojError(
                f"compensation '{name}' is {image.shape[1]}x{image.shape[0]}, the original {original.shape[1]}x{original.shape[0]}"
            )
        rows.append(_row(name, crop.cut(to_uint8(blur(image))), reference, peak))
    return rows


def _row(name: str, blurred: np.ndarray, reference: np.ndarray, peak: float) -> ProtocolScore:
    mse = float(np.mean((blurred - reference) ** 2))
    psnr = math.inf if mse == 0 else 10.0 * math.log10(peak**2 / mse)
    return ProtocolScore(name, matlab_ssim(blurred, reference)[0], psnr, math.sqrt(mse))


def image_counts(counts: np.ndarray) -> np.ndarray:
    """An image file's integer counts ``(H, W, 3)`` (8- or 16-bit) as the 8-bit levels ``0..255`` that an
    8-bit projector shows (float64; a 16-bit file rounded to the nearest 8-bit level)."""
    counts = np.asarray(counts)
    if counts.dtype == np.uint8:
        return counts.astype(np.float64)
    top = float(np.iinfo(counts.dtype).max) if np.issubdtype(counts.dtype, np.integer) else 1.0
    return np.round(counts.astype(np.float64) * (255.0 / top))


@dataclass
class ProtocolBlur:
    """A measured blur as the protocol uses it: ``forward`` (``A``) and ``adjoint`` (``A^T``) on torch
    ``(1, 3, H, W)`` float64 images in ``[0, 1]``, ``norm_bound >= ||A||_2`` per channel, and a line
    naming it; :meth:`blur` is the :data:`Blur` on ``0..255`` arrays. ``solve_forward`` and
    ``solve_adjoint`` (default: the same): a faster, less exact form for the optimum's iterations."""

    title: str
    forward: Callable
    adjoint: Callable
    norm_bound: np.ndarray
    solve_forward: Callable | None = None
    solve_adjoint: Callable | None = None

    def blur(self, image: np.ndarray) -> np.ndarray:
        import torch

        x = torch.from_numpy(np.ascontiguousarray(np.moveaxis(np.asarray(image, np.float64) / 255.0, -1, 0)))
        with torch.no_grad():
            y = self.forward(x[None])[0]
        return np.moveaxis(y.numpy(), 0, -1) * 255.0


def least_squares_optimum(
    original: np.ndarray, blur: ProtocolBlur, crop: Crop | None = None, iterations: int = 200
) -> tuple[np.ndarray, float]:
    """The compensation that minimizes the protocol's squared error: ``x`` in ``[0, 1]`` minimizing
    ``1/2 || M (A x - t) ||^2``, ``t`` the original ``(H, W, 3)`` in ``0..255`` divided by 255, ``M``
    the crop, ``A`` the blur; by :func:`edofproj.compensation.constrained.box_least_squares` (monotone
    FISTA, step ``1 / norm_bound^2``), ``iterations`` steps from ``t`` (``1/2`` outside the crop).
    Returns ``255 x`` ``(H, W, 3)`` (not rounded) and the share of the objective's decrease that the
    last tenth of the iterations made (small: converged)."""
    import torch

    from ..compensation.constrained import box_least_squares

    original = np.asarray(original, dtype=np.float64)
    H, W = original.shape[:2]
    crop = (crop or Crop(0, H, 0, W)).check((H, W))
    mask = torch.zeros(1, 1, H, W, dtype=torch.float64)
    mask[..., crop.y0 : crop.y1, crop.x0 : crop.x1] = 1.0
    target = torch.from_numpy(np.ascontiguousarray(np.moveaxis(original / 255.0, -1, 0)))[None] * mask
    bound = torch.as_tensor(np.asarray(blur.norm_bound, dtype=np.float64)).reshape(1, -1, 1, 1)
    forward = blur.solve_forward or blur.forward
    adjoint = blur.solve_adjoint or blur.adjoint
    x, objective = box_least_squares(
        target,
        lambda v: forward(v) * mask,
        lambda r: adjoint(r * mask),
        1.0 / bound.square(),
        iterations=iterations,
        start=target + (1 - mask) * 0.5,
        return_objective=True,
    )
    f = objective.reshape(len(objective), -1).sum(dim=1).numpy()
    tail = f[-1 - max(iterations // 10, 1)] - f[-1] if iterations >= 1 else 0.0
    share = float(tail / (f[0] - f[-1])) if f[0] > f[-1] else 0.0
    return np.moveaxis(x[0].numpy(), 0, -1) * 255.0, share


def lab_protocol_blur(fields: Sequence, title: str) -> ProtocolBlur:
    """The :class:`ProtocolBlur` of three :class:`.lab_kernels.LabKernelField` (channel ``c`` blurred by
    ``fields[c]``; the same field three times for their script's red kernels); the optimum iterates
    with float32 copies of the kernels."""
    import torch

    def each(planes_fields: Sequence, method: str) -> Callable:
        def apply(v):
            planes = [getattr(f, method)(v[0, c].numpy()) for c, f in enumerate(planes_fields)]
            return torch.from_numpy(np.stack(planes).astype(np.float64))[None]

        return apply

    if len(fields) != 3:
        raise EdofprojError(f"an RGB blur needs three kernel fields, got {len(fields)}")
    bounds = {id(f): f.norm_bound() for f in fields}
    fast = {id(f): f.astype(np.float32) for f in fields}
    solve = [fast[id(f)] for f in fields]
    return ProtocolBlur(
        title,
        each(fields, "apply"),
        each(fields, "adjoint"),
        np.array([bounds[id(f)] for f in fields]) * (1 + 1e-6),
        each(solve, "apply"),
        each(solve, "adjoint"),
    )


def psf_map_protocol_blur(path, image_hw: tuple[int, int]) -> ProtocolBlur:
    """The :class:`ProtocolBlur` of the PSF map file ``path``, Gaussian or kernel map
    (:func:`.measured_blur.map_file_blur`: each colour its own map where the file has one, else the one
    map for all three) for images of ``image_hw``."""
    from .measured_blur import map_file_blur

    op = map_file_blur(path)
    if (op.height, op.width) != tuple(image_hw):
        raise EdofprojError(
            f"the PSF map '{path}' is of a {op.width}x{op.height} projector, the image {image_hw[1]}x{image_hw[0]}"
        )
    stored = read_arrays(path, what="PSF map")
    maps = [str(c) for c in np.atleast_1d(stored["channels"])] if "channels" in stored else ["mean"]
    colours = [c for c in ("red", "green", "blue") if c in maps]
    names = f"the maps of {', '.join(colours)}" + (" (the others the white map)" if len(colours) < 3 else "")
    title = f"PSF map '{path}': " + (names if colours else f"its {maps[0]} map for R, G and B")
    bound = np.broadcast_to(np.asarray(op.norm_bound(), dtype=np.float64).reshape(-1), (3,)).copy()
    return ProtocolBlur(title, op.forward, op.adjoint, bound)
