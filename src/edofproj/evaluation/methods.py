"""The compared methods: an optical design plus a compensation, all through one image formation.

For a target image ``I`` and a flat screen at depth ``z`` with the design's PSF ``p_z``, every
method goes through the same three steps (:mod:`edofproj.imaging.projection`):

    I*      = project(I, p_z)                        the uncompensated projection (simulated capture)
    x       = compensate(I, I*, p_z)                 the projector input
    display = project(clamp(x, 0, 1), p_z)           what the screen shows; scored against I

``project`` clamps its input to ``[0, 1]``: a projector emits no negative light and saturates.
The methods, by name:

==================== ================= =====================================================
name                 optics            compensation
==================== ================= =====================================================
``lens``             bare lens         none (``x = I``)
``lens+wiener``      bare lens         Wiener deconvolution with the known PSF; NSR tuned (for
                                       SSIM by default) on *training* images over the scored
                                       depth range
``lens+cls``         bare lens         box-constrained least squares with the known PSF
``lens+net``         bare lens         our U-Net trained on lens-only PSFs (a separate run)
``lens+onlineprodeb`` bare lens        OnlineProDeb (re-implementation), trained on the same
                                       simulated lens-only data (a separate run)
``doe``              the run's DOE     none
``doe+wiener``       the run's DOE     Wiener, NSR tuned for this design
``doe+ensemble``     the run's DOE     one depth-ensemble Wiener filter for every depth (blind:
                                       the filter the real-time network starts from), NSR
                                       tuned on training images
``doe+net``          the run's DOE     the run's jointly trained U-Net (ours)
``cubic+net``        cubic phase plate the U-Net trained with that plate (a separate run)
``axicon+net``       axicon            the U-Net trained with that axicon (a separate run)
==================== ================= =====================================================

**Blind and non-blind.** A *blind* method knows nothing of the screen's depth or PSF at run
time: no compensation, the networks (they see ``I`` and the simulated capture ``I*``, their
second input as in training, never the PSF) and ``doe+ensemble`` (one fixed filter for the
whole depth range). A *non-blind* method is given the exact PSF ``p_z`` of the depth it
compensates: Wiener (``*+wiener``) and constrained least squares (``*+cls``). A projector that
does not measure the screen's depth can only run a blind method; the non-blind ones are an
upper reference, not a competitor on equal terms (:attr:`MethodSpec.blind`).
Separate runs are found as sub-directories of a *baselines* directory, named by
:data:`BASELINE_RUN_DIRS` (``lens+net`` -> ``lens_net``, ...), and are trained with the
evaluated run's configuration plus :attr:`MethodSpec.train_overrides`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

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
from ..data import build_training_source
from ..errors import EdofprojError
from ..imaging.convolution import convolve_same
from ..imaging.projection import project
from ..metrics import ssim

#: ``compensate(target, captured, psf) -> projector input``, tensors ``(1, 3, H, W)`` and ``(1, 3, K, K)``.
Compensator = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class MethodSpec:
    """A method's definition: which optics, which compensation, and which run provides them.

    ``optics``: ``"lens"`` (the bare lens), ``"run"`` (the evaluated run's DOE) or
    ``"baseline"`` (the DOE of the separate run ``run_dir``). ``compensation``: ``"none"``,
    ``"wiener"``, ``"cls"``, ``"ensemble"`` (one depth-ensemble Wiener filter) or ``"net"`` (the network of the evaluated run when ``run_dir`` is
    None, else of ``run_dir``). ``train_overrides``: config overrides that turn the evaluated
    run's configuration into this baseline's training run.
    """

    name: str
    optics: str
    compensation: str
    summary: str
    run_dir: str | None = None
    train_overrides: tuple[str, ...] = field(default_factory=tuple)

    @property
    def needs_separate_run(self) -> bool:
        return self.run_dir is not None

    @property
    def blind(self) -> bool:
        """True when the method runs without knowing the screen's depth or PSF (module docstring)."""
        return self.compensation not in NON_BLIND_COMPENSATIONS


#: Compensations that are given the exact PSF of each depth.
NON_BLIND_COMPENSATIONS = frozenset({"wiener", "cls"})


METHODS: tuple[MethodSpec, ...] = (
    MethodSpec("lens", "lens", "none", "bare lens, no compensation"),
    MethodSpec("lens+wiener", "lens", "wiener", "bare lens + non-blind Wiener deconvolution"),
    MethodSpec("lens+cls", "lens", "cls", "bare lens + box-constrained least squares (non-blind)"),
    MethodSpec(
        "lens+net",
        "lens",
        "net",
        "bare lens + our U-Net trained on lens-only PSFs (separate run)",
        run_dir="lens_net",
        train_overrides=("doe.kind=lens",),
    ),
    MethodSpec(
        "lens+onlineprodeb",
        "lens",
        "net",
        "bare lens + OnlineProDeb (our re-implementation), trained on the same simulated lens-only data",
        run_dir="lens_onlineprodeb",
        train_overrides=("doe.kind=lens", "net.architecture=onlineprodeb"),
    ),
    MethodSpec("doe", "run", "none", "learned DOE, no compensation"),
    MethodSpec("doe+wiener", "run", "wiener", "learned DOE + non-blind Wiener deconvolution"),
    MethodSpec(
        "doe+ensemble",
        "run",
        "ensemble",
        "learned DOE + one depth-ensemble Wiener filter for every depth (blind linear baseline)",
    ),
    MethodSpec("doe+net", "run", "net", "learned DOE + jointly trained U-Net (ours)"),
    MethodSpec(
        "cubic+net",
        "baseline",
        "net",
        "cubic phase plate + the same U-Net trained with it (separate run)",
        run_dir="cubic_net",
        train_overrides=("doe.kind=cubic",),
    ),
    MethodSpec(
        "axicon+net",
        "baseline",
        "net",
        "axicon + the same U-Net trained with it (separate run)",
        run_dir="axicon_net",
        train_overrides=("doe.kind=axicon",),
    ),
)

METHOD_NAMES: tuple[str, ...] = tuple(m.name for m in METHODS)
BASELINE_RUN_DIRS: dict[str, str] = {m.name: m.run_dir for m in METHODS if m.run_dir}
#: The method the evaluated run itself provides (its DOE and its network).
OURS = "doe+net"


def method_spec(name: str) -> MethodSpec:
    """The :class:`MethodSpec` called ``name``; unknown names raise with the list of known ones."""
    for spec in METHODS:
        if spec.name == name:
            return spec
    raise EdofprojError(f"unknown method '{name}' (known: {', '.join(METHOD_NAMES)})")


def select_methods(names: Sequence[str] | None) -> list[MethodSpec]:
    """The specs of ``names`` in the canonical order (None or empty: all methods)."""
    if not names:
        return list(METHODS)
    wanted = {method_spec(name).name for name in names}
    return [spec for spec in METHODS if spec.name in wanted]


# --------------------------------------------------------------------------- compensations


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


@dataclass
class PreparedMethod:
    """A method ready to run: its spec, its optical design, its compensation, a note for the report."""

    spec: MethodSpec
    design: object  # :class:`~edofproj.evaluation.designs.OpticalDesign`
    compensate: Compensator
    detail: str = ""

    @property
    def name(self) -> str:
        return self.spec.name


# --------------------------------------------------------------------------- Wiener NSR


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
    scores: dict[float, float] = {}
    with torch.no_grad():
        for nsr in candidates if candidates is not None else DEFAULT_NSR_CANDIDATES:
            compensate = EnsembleWienerCompensation(ensemble, float(nsr), ensemble_radius(cfg))
            x = compensate(train_images, train_images, ensemble[:1])
            total = sum(float(metric(project(x, p.unsqueeze(0)), train_images).mean()) for p in tuning)
            scores[float(nsr)] = total / len(tuning)
    best = max(scores, key=scores.__getitem__)
    return best, scores
