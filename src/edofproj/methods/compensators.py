"""The compensations of :mod:`.catalogue`'s methods, and the tuning of their linear filters.

Every compensation is a callable ``compensate(target, captured, psf) -> projector input`` with
``target`` and ``captured`` ``(B, 3, H, W)`` and ``psf`` ``(1, 3, K, K)``, the PSF of the screen's
depth: the non-blind ones (Wiener, constrained least squares) use it, the blind ones ignore it.
The linear filters' noise-to-signal ratios are tuned on *training* crops, never on test images.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from ..compensation.constrained import box_constrained_deconvolution
from ..compensation.wiener import (
    DEFAULT_NSR_CANDIDATES,
    depth_ensemble_wiener_kernel,
    psnr,
    tune_wiener_nsr,
    wiener_deconvolve,
)
from ..cpu_tasks import default_workers, run_tasks
from ..data import build_training_source
from ..imaging.convolution import convolve_same
from ..imaging.projection import project
from ..metrics import ssim

#: ``compensate(target, captured, psf) -> projector input``, tensors ``(B, 3, H, W)`` and ``(1, 3, K, K)``.
Compensator = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def no_compensation(target: torch.Tensor, captured: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """``x = I``: the image is projected as it is."""
    return target


class WienerCompensation:
    """``x = clamp(F^-1{conj(H) F{I} / (|H|^2 + NSR)}, 0, 1)`` with the known PSF (:mod:`edofproj.compensation.wiener`)."""

    def __init__(self, nsr: float) -> None:
        self.nsr = float(nsr)

    def __call__(self, target, captured, psf):
        return wiener_deconvolve(target, psf, self.nsr)


class ConstrainedCompensation:
    """``x = argmin_{0<=x<=1} ||p * x + h mean(x) - I||^2`` by FISTA (:mod:`edofproj.compensation.constrained`)."""

    def __init__(self, iterations: int) -> None:
        self.iterations = int(iterations)

    def __call__(self, target, captured, psf):
        return box_constrained_deconvolution(target, psf, iterations=self.iterations)


class EnsembleWienerCompensation:
    """``x = clamp(g * I, 0, 1)``: one fixed linear filter for every depth, blind to the depth.

    ``g`` is :func:`~edofproj.compensation.wiener.depth_ensemble_wiener_kernel` of PSFs
    ``(N, C, K, K)`` spanning the depth range (the filter the real-time network starts from),
    ``G = sum_z conj(H_z) / (sum_z |H_z|^2 + N NSR)``, kept to ``(2 radius + 1)^2`` taps on a
    ``grid``-px frame. The target is reflect-padded by ``radius`` before the convolution, as the
    Wiener baseline is, so the image borders are not darkened by zero padding.
    """

    def __init__(self, psfs, nsr: float, radius: int, grid: int = 256) -> None:
        if isinstance(psfs, torch.Tensor):
            psfs = psfs.detach().cpu().numpy()
        self.nsr = float(nsr)
        self.radius = int(radius)
        self.kernel = torch.as_tensor(
            depth_ensemble_wiener_kernel(psfs, self.nsr, radius=self.radius, grid=grid), dtype=torch.float32
        ).unsqueeze(0)

    def __call__(self, target, captured, psf):
        r = self.radius
        padded = F.pad(target, (r, r, r, r), mode="reflect")
        filtered = convolve_same(padded, self.kernel.to(target.device))
        return filtered[..., r:-r, r:-r].clamp(0.0, 1.0) if r else filtered.clamp(0.0, 1.0)


class NetworkCompensation:
    """``x = net(I, I*)``: a blind compensation network (it never sees the PSF)."""

    def __init__(self, net: torch.nn.Module) -> None:
        self.net = net.eval()

    def __call__(self, target, captured, psf):
        return self.net(target, captured)


# --------------------------------------------------------------------------- tuning the linear filters


def training_crops(cfg, count: int, seed: int = 0) -> torch.Tensor:
    """``count`` training crops ``(count, 3, crop, crop)`` of the run's training source (never test images)."""
    source = build_training_source(cfg.data, cfg.train.seed)
    generator = torch.Generator().manual_seed(int(seed))
    return source.sample(int(count), cfg.data.crop, generator)


def score_range_mm(cfg) -> tuple[float, float]:
    """Depths (mm) over which means and worst depths are taken: ``evaluation.score_range_mm``, or
    the training range when that is empty."""
    if cfg.evaluation.score_range_mm:
        near, far = cfg.evaluation.score_range_mm
        return float(near), float(far)
    return float(cfg.psf.depth_min_mm), float(cfg.psf.depth_max_mm)


def tune_nsr(design, train_images: torch.Tensor, cfg) -> tuple[float, dict[float, float]]:
    """The Wiener NSR of ``design`` that maximizes the mean ``evaluation.wiener_tuning_metric``
    (SSIM or PSNR) of the compensated projection of the *training* crops over
    ``evaluation.wiener_tuning_depths`` depths of the scored range."""
    near_mm, far_mm = score_range_mm(cfg)
    depths_m = np.linspace(near_mm, far_mm, cfg.evaluation.wiener_tuning_depths) * 1e-3
    metric = ssim if cfg.evaluation.wiener_tuning_metric == "ssim" else "psnr"
    return tune_wiener_nsr(train_images, design.psf(depths_m), project, metric=metric)


def ensemble_depths_m(cfg, count: int = 32) -> np.ndarray:
    """``count`` depths (m) of the scored range, uniform in 1/z (uniform in defocus), for the
    depth-ensemble filter."""
    near_mm, far_mm = score_range_mm(cfg)
    return 1.0 / np.linspace(1.0 / (near_mm * 1e-3), 1.0 / (far_mm * 1e-3), int(count))


def ensemble_radius(cfg) -> int:
    """Half-width of the depth-ensemble filter: the PSF window (``psf.window``) on each side."""
    return int(cfg.psf.window)


def tune_ensemble_nsr(design, train_images: torch.Tensor, cfg, candidates=None) -> tuple[float, dict[float, float]]:
    """The NSR of the depth-ensemble filter of ``design`` that maximizes the mean
    ``evaluation.wiener_tuning_metric`` of the compensated projection of the *training* crops over
    ``evaluation.wiener_tuning_depths`` depths of the scored range (as :func:`tune_nsr`)."""
    near_mm, far_mm = score_range_mm(cfg)
    tuning = design.psf(np.linspace(near_mm, far_mm, cfg.evaluation.wiener_tuning_depths) * 1e-3)
    ensemble = design.psf(ensemble_depths_m(cfg))
    metric = ssim if cfg.evaluation.wiener_tuning_metric == "ssim" else psnr

    def mean_score(nsr: float) -> float:
        compensate = EnsembleWienerCompensation(ensemble, nsr, ensemble_radius(cfg))
        x = compensate(train_images, train_images, ensemble[:1])
        return sum(float(metric(project(x, p.unsqueeze(0)), train_images).mean()) for p in tuning) / len(tuning)

    nsrs = [float(nsr) for nsr in (candidates if candidates is not None else DEFAULT_NSR_CANDIDATES)]
    # the candidates are independent: one task each on the CPU's cores (edofproj.cpu_tasks)
    tasks = [partial(mean_score, nsr) for nsr in nsrs]
    scores = dict(zip(nsrs, run_tasks(tasks, default_workers(train_images.device))))
    best = max(scores, key=scores.__getitem__)
    return best, scores
