"""Non-blind Wiener deconvolution: the classical baseline with the PSF known (method ``lens+wiener``).

For a projection ``I* = p ⊛ x + h · mean(x)`` (PSF ``p``, haze fraction ``h = 1 - Σp``, see
:mod:`edofproj.imaging`), the Wiener estimate of the projector input that would give the
target ``I`` is, per colour channel,

    X̂(k) = conj(H(k)) · I(k) / (|H(k)|² + NSR),        x̂ = clamp(F⁻¹{X̂}, 0, 1)

where ``H`` is the optical transfer function (:func:`edofproj.imaging.convolution.optical_transfer_function`,
the project's one FFT operator: the DFT of the PSF, centred on its optical
axis) and ``NSR`` the noise-to-signal power ratio, the one free parameter.

**Haze.** ``h · mean(x)`` is a constant image: it only adds to the zero-frequency bin, where
it contributes ``h · X(0)``. The effective transfer function is therefore ``H`` with
``H(0) = Σp + h = 1``: the haze keeps the mean brightness, it never blurs. ``haze=True``
(the default) uses that ``H``; ``haze=False`` the PSF's own spectrum. The mean is taken
over the padded frame, so with padding this is an approximation (exact without padding).

**Borders.** The DFT treats the image as periodic, while the projection pads with zeros.
The image is therefore extended by reflection (by at least ``K`` pixels on each side, more
to reach a fast FFT length, :func:`edofproj.imaging.convolution.fast_fft_length`) before filtering and cropped
afterwards; ``pad=False`` filters the frame as it is (periodic model, exact inverse of a
circular blur).

Two implementations with the same result: :class:`WienerCompensator` (NumPy /
:mod:`scipy.fft` with worker threads; the filter ``conj(H)/(|H|²+NSR)`` is cached per frame
size, so a video costs one forward and one inverse real FFT per channel and frame) and
:func:`wiener_deconvolve` / :class:`TorchWienerCompensator` (PyTorch, differentiable, runs
on a GPU). :func:`tune_wiener_nsr` picks the NSR on *training* images.
"""

from __future__ import annotations

import os
from functools import partial
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ..cpu_tasks import default_workers, run_tasks
from ..errors import EdofprojError
from ..imaging.convolution import fast_fft_length, optical_transfer_function

#: Default NSR candidates searched by :func:`tune_wiener_nsr` (log-spaced, 1e-5 … 1e-1).
DEFAULT_NSR_CANDIDATES = np.logspace(-5, -1, 13)


# --------------------------------------------------------------------------- geometry


def _psf_3d(psf) -> np.ndarray:
    """A PSF as a float64 array (C, K, K); accepts (C,K,K) or (1,C,K,K), numpy or torch."""
    if isinstance(psf, torch.Tensor):
        psf = psf.detach().cpu().numpy()
    psf = np.asarray(psf, dtype=np.float64)
    if psf.ndim == 4 and psf.shape[0] == 1:
        psf = psf[0]
    if psf.ndim != 3 or psf.shape[-1] != psf.shape[-2] or psf.shape[-1] % 2 == 0:
        raise EdofprojError(f"the Wiener filter needs one PSF of shape (C, K, K) with K odd, got {tuple(psf.shape)}")
    if not np.all(np.isfinite(psf)):
        raise EdofprojError("the PSF contains NaN or infinite values")
    return psf


def padding_for(height: int, width: int, window: int, pad: bool = True) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) reflection padding for a frame and a K×K PSF.

    At least ``K`` pixels on each side, then extended at the bottom/right to the next
    fast FFT length. Raises if the frame is too small to reflect (``H, W`` must exceed the pad).
    """
    if not pad:
        return (0, 0, 0, 0)
    k = int(window)
    total_h = fast_fft_length(height + 2 * k)
    total_w = fast_fft_length(width + 2 * k)
    top, left = k, k
    bottom, right = total_h - height - k, total_w - width - k
    if max(top, bottom) >= height or max(left, right) >= width:
        raise EdofprojError(
            f"a {height}x{width} image is too small for Wiener deconvolution with a {k}x{k} PSF "
            f"(needs more than {max(top, bottom, left, right)} pixels per side; use a smaller psf window)"
        )
    return top, bottom, left, right


def _otf_numpy(psf: np.ndarray, height: int, width: int, haze: bool) -> np.ndarray:
    """:func:`~edofproj.imaging.convolution.optical_transfer_function` of a ``(C, K, K)`` array, complex128."""
    return optical_transfer_function(torch.from_numpy(psf), (height, width), haze=haze).numpy()


def checked_nsr(nsr: float) -> float:
    """``nsr`` as a float, or a one-line error unless it is finite and >= 0."""
    value = float(nsr)
    if not (np.isfinite(value) and value >= 0):
        raise EdofprojError(f"Wiener NSR={nsr} must be a finite number >= 0")
    return value


def wiener_filter(otf: np.ndarray, nsr: float) -> np.ndarray:
    """The Wiener filter ``G = conj(H) / (|H|² + NSR)``."""
    return np.conj(otf) / (np.abs(otf) ** 2 + checked_nsr(nsr))


def depth_ensemble_wiener_kernel(psfs, nsr: float, radius: int, grid: int = 128) -> np.ndarray:
    """The best *fixed* linear compensation for a screen at an unknown depth, as a small kernel.

    For PSFs ``p_z`` at depths drawn uniformly from ``psfs`` ``(N, C, K, K)`` (e.g. a table uniform
    in 1/z), the filter that minimizes the expected ``E_z |H_z G I - I|^2 + NSR |G I|^2`` is

        G(k) = sum_z conj(H_z(k)) / (sum_z |H_z(k)|^2 + N NSR)

    (with one PSF, the Wiener filter; ``H_z`` with the haze,
    :func:`edofproj.imaging.convolution.optical_transfer_function`).
    Its convolution kernel ``g = F^-1[G]`` (computed on a ``grid x grid`` frame) is cut to
    ``(2 radius + 1)^2`` taps around the centre, and the DC gain the cut tail carried,
    ``G(0) - sum(cut)``, is added back spread by a normalized Gaussian (sigma = radius / 2), so
    that flat areas keep the brightness ``G(0)``. Returns float64 ``(C, 2 radius + 1, 2 radius + 1)``
    convolution kernels (apply as ``x = g * I``; flip both axes for a cross-correlation).
    """
    psfs = np.asarray(psfs, dtype=np.float64)
    if psfs.ndim == 3:
        psfs = psfs[None]
    if psfs.ndim != 4 or psfs.shape[0] < 1:
        raise EdofprojError(f"PSFs must be (N, C, K, K), got shape {psfs.shape}")
    radius = int(radius)
    if radius < 0 or 2 * radius + 1 > grid:
        raise EdofprojError(f"kernel radius {radius} must be >= 0 and fit in the {grid}-px grid")
    otfs = np.stack([_otf_numpy(p, grid, grid, haze=True) for p in psfs])  # (N, C, grid, grid/2+1)
    gain = np.conj(otfs).sum(0) / ((np.abs(otfs) ** 2).sum(0) + len(psfs) * checked_nsr(nsr))
    kernel = np.fft.fftshift(np.fft.irfft2(gain, s=(grid, grid)), axes=(-2, -1))
    centre = grid // 2
    cut = kernel[:, centre - radius : centre + radius + 1, centre - radius : centre + radius + 1].copy()
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    spread = np.exp(-(yy**2 + xx**2) / (2 * max(radius / 2, 0.5) ** 2))
    spread /= spread.sum()
    cut += (gain[:, 0, 0].real - cut.sum(axis=(-2, -1)))[:, None, None] * spread
    return cut


# --------------------------------------------------------------------------- NumPy / SciPy


class WienerCompensator:
    """Wiener deconvolution with NumPy/SciPy, the filter cached per frame size.

    ``comp = WienerCompensator(psf, nsr)``; ``comp(image)`` with ``image`` ``(C,H,W)`` or
    ``(B,C,H,W)`` (NumPy or torch, values in [0, 1]) returns a float32 NumPy array of the
    same shape in [0, 1]. Computation runs in single precision (complex64 spectra) with
    ``workers`` FFT threads (default: all CPUs).
    """

    def __init__(self, psf, nsr: float, haze: bool = True, pad: bool = True, workers: int | None = None):
        self.psf = _psf_3d(psf)
        self.nsr = checked_nsr(nsr)
        self.haze = bool(haze)
        self.pad = bool(pad)
        self.workers = int(workers) if workers else (os.cpu_count() or 1)
        self._filters: dict[tuple[int, int], tuple[tuple[int, int, int, int], np.ndarray]] = {}

    @property
    def window(self) -> int:
        return int(self.psf.shape[-1])

    def filter_for(self, height: int, width: int) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """(padding, complex64 filter (C, Hp, Wp//2+1)) for a frame size, computed once."""
        key = (int(height), int(width))
        if key not in self._filters:
            pads = padding_for(height, width, self.window, self.pad)
            otf = _otf_numpy(self.psf, height + pads[0] + pads[1], width + pads[2] + pads[3], self.haze)
            self._filters[key] = (pads, wiener_filter(otf, self.nsr).astype(np.complex64))
        return self._filters[key]

    def __call__(self, image) -> np.ndarray:
        if isinstance(image, torch.Tensor):
            image = image.detach().cpu().numpy()
        image = np.asarray(image, dtype=np.float32)
        if image.ndim not in (3, 4) or image.shape[-3] != self.psf.shape[0]:
            raise EdofprojError(
                f"Wiener input must be (C,H,W) or (B,C,H,W) with C={self.psf.shape[0]}, got {image.shape}"
            )
        height, width = image.shape[-2:]
        (top, bottom, left, right), filt = self.filter_for(height, width)
        lead = [(0, 0)] * (image.ndim - 2)
        padded = np.pad(image, lead + [(top, bottom), (left, right)], mode="reflect") if self.pad else image
        import scipy.fft  # here, not at import: a third of a second of every command's start

        spectrum = scipy.fft.rfft2(padded, axes=(-2, -1), workers=self.workers)
        spectrum *= filt
        restored = scipy.fft.irfft2(spectrum, s=padded.shape[-2:], axes=(-2, -1), workers=self.workers)
        restored = restored[..., top : top + height, left : left + width]
        return np.clip(restored, 0.0, 1.0).astype(np.float32, copy=False)


# --------------------------------------------------------------------------- PyTorch


def _check_torch_inputs(image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    if image.ndim != 4:
        raise EdofprojError(f"image must be (B, C, H, W), got {tuple(image.shape)}")
    if psf.ndim == 3:
        psf = psf.unsqueeze(0)
    if (
        psf.ndim != 4
        or psf.shape[-1] != psf.shape[-2]
        or psf.shape[-1] % 2 == 0
        or psf.shape[1] not in (1, image.shape[1])
        or psf.shape[0] not in (1, image.shape[0])
    ):
        raise EdofprojError(
            f"PSF must be (C|1,K,K) or (1|B,C|1,K,K) with K odd matching image {tuple(image.shape)}, "
            f"got {tuple(psf.shape)}"
        )
    return psf


def _torch_wiener_filter(psf: torch.Tensor, height: int, width: int, nsr: float, haze: bool, pad: bool):
    """(padding, complex filter (N, C, Hp, Wp//2+1)) for frames of ``height × width``."""
    pads = padding_for(height, width, psf.shape[-1], pad)
    otf = optical_transfer_function(psf, (height + pads[0] + pads[1], width + pads[2] + pads[3]), haze=haze)
    return pads, otf.conj() / (otf.abs() ** 2 + checked_nsr(nsr))


def _apply_torch_filter(image: torch.Tensor, pads: tuple[int, int, int, int], filt: torch.Tensor) -> torch.Tensor:
    """Reflect-pad, filter in the Fourier domain, crop, clamp to [0, 1]."""
    top, bottom, left, right = pads
    height, width = image.shape[-2:]
    padded = F.pad(image, (left, right, top, bottom), mode="reflect") if any(pads) else image
    restored = torch.fft.irfft2(torch.fft.rfft2(padded) * filt, s=padded.shape[-2:])
    return restored[..., top : top + height, left : left + width].clamp(0.0, 1.0)


def wiener_deconvolve(
    image: torch.Tensor, psf: torch.Tensor, nsr: float, haze: bool = True, pad: bool = True
) -> torch.Tensor:
    """PyTorch Wiener deconvolution, ``clamp(F⁻¹{conj(H)·F{I}/(|H|²+NSR)}, 0, 1)``.

    ``image`` (B, C, H, W); ``psf`` (C, K, K) or (1|B, C, K, K) (one PSF per sample; a PSF
    channel axis of 1 applies to every colour channel).
    Differentiable, on the device of ``image``; same padding and haze model as
    :class:`WienerCompensator`.
    """
    psf = _check_torch_inputs(image, psf).to(image.device, image.dtype)
    pads, filt = _torch_wiener_filter(psf, image.shape[-2], image.shape[-1], nsr, haze, pad)
    return _apply_torch_filter(image, pads, filt)


class TorchWienerCompensator:
    """:func:`wiener_deconvolve` with the filter cached per (frame size, device, dtype).

    For repeated frames on a GPU: ``comp = TorchWienerCompensator(psf, nsr)``;
    ``comp(image)`` with ``image`` (B, C, H, W) on any device.
    """

    def __init__(self, psf, nsr: float, haze: bool = True, pad: bool = True):
        self.psf = torch.as_tensor(_psf_3d(psf), dtype=torch.float32).unsqueeze(0)
        self.nsr = checked_nsr(nsr)
        self.haze = bool(haze)
        self.pad = bool(pad)
        self._filters: dict = {}

    def __call__(self, image: torch.Tensor) -> torch.Tensor:
        _check_torch_inputs(image, self.psf)
        key = (image.shape[-2], image.shape[-1], image.device, image.dtype)
        if key not in self._filters:
            psf = self.psf.to(image.device, image.dtype)
            self._filters[key] = _torch_wiener_filter(psf, key[0], key[1], self.nsr, self.haze, self.pad)
        return _apply_torch_filter(image, *self._filters[key])


# --------------------------------------------------------------------------- NSR selection


def psnr(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Peak signal-to-noise ratio per image, ``10·log10(1 / MSE)`` for images in [0, 1]."""
    mse = ((prediction - target) ** 2).flatten(1).mean(dim=1)
    return 10.0 * torch.log10(1.0 / mse.clamp_min(1e-12))


def tune_wiener_nsr(
    train_images: torch.Tensor,
    psf: torch.Tensor,
    project_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    candidates: Sequence[float] | np.ndarray = DEFAULT_NSR_CANDIDATES,
    metric: str | Callable[[torch.Tensor, torch.Tensor], torch.Tensor] = "psnr",
    haze: bool = True,
) -> tuple[float, dict[float, float]]:
    """The NSR that maximizes the mean ``metric(project(Wiener(I)), I)`` over *training* images.

    ``train_images`` (B, C, H, W) in [0, 1]; ``psf`` (C, K, K) or (N, C, K, K): with N > 1 the
    score is averaged over all N PSFs (one NSR for a whole depth range). ``project_fn(x, psf)``
    is the forward model (:func:`edofproj.imaging.project`); ``metric`` ``"psnr"`` or a callable
    ``(pred, target) -> per-image scores`` (higher is better). Returns ``(best_nsr, {nsr: score})``.
    Never pass test images here: the NSR is a trained parameter of the baseline.
    """
    metric_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    if isinstance(metric, str):
        if metric != "psnr":
            raise EdofprojError(f"unknown Wiener tuning metric '{metric}' (known: psnr, or a callable)")
        metric_fn = psnr
    else:
        metric_fn = metric
    candidates = [float(c) for c in candidates]
    if not candidates:
        raise EdofprojError("tune_wiener_nsr needs at least one NSR candidate")
    psf = torch.as_tensor(psf, dtype=train_images.dtype)
    psfs = psf.unsqueeze(0) if psf.ndim == 3 else psf

    def mean_score(nsr: float) -> float:
        total = 0.0
        for one in psfs:
            one = one.unsqueeze(0)
            restored = wiener_deconvolve(train_images, one, nsr, haze=haze)
            total += float(metric_fn(project_fn(restored, one), train_images).mean())
        return total / len(psfs)

    # the candidates are independent: one task each on the CPU's cores (edofproj.cpu_tasks)
    tasks = [partial(mean_score, nsr) for nsr in candidates]
    workers = default_workers(train_images.device)
    scores = dict(zip(candidates, run_tasks(tasks, workers)))
    best = max(scores, key=scores.__getitem__)
    return best, scores
