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
``doe+net``          the run's DOE     the run's jointly trained U-Net (ours)
``cubic+net``        cubic phase plate the U-Net trained with that plate (a separate run)
``axicon+net``       axicon            the U-Net trained with that axicon (a separate run)
==================== ================= =====================================================

The networks are blind: they see ``I`` and the simulated capture ``I*`` (their second input,
as in training), never the PSF. Wiener and CLS are non-blind: they are given ``p_z``.
Separate runs are found as sub-directories of a *baselines* directory, named by
:data:`BASELINE_RUN_DIRS` (``lens+net`` -> ``lens_net``, ...), and are trained with the
evaluated run's configuration plus :attr:`MethodSpec.train_overrides`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch

from ..errors import EdofprojError

#: ``compensate(target, captured, psf) -> projector input``, tensors ``(1, 3, H, W)`` and ``(1, 3, K, K)``.
Compensator = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class MethodSpec:
    """A method's definition: which optics, which compensation, and which run provides them.

    ``optics``: ``"lens"`` (the bare lens), ``"run"`` (the evaluated run's DOE) or
    ``"baseline"`` (the DOE of the separate run ``run_dir``). ``compensation``: ``"none"``,
    ``"wiener"``, ``"cls"`` or ``"net"`` (the network of the evaluated run when ``run_dir`` is
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
        from ..compensation.wiener import wiener_deconvolve

        return wiener_deconvolve(target, psf, self.nsr)


class ConstrainedCompensation:
    """``x = argmin_{0<=x<=1} ||p * x + h mean(x) - I||^2`` by FISTA (:mod:`edofproj.compensation.constrained`)."""

    def __init__(self, iterations: int) -> None:
        self.iterations = int(iterations)

    def __call__(self, target, captured, psf):
        from ..compensation.constrained import box_constrained_deconvolution

        return box_constrained_deconvolution(target, psf, iterations=self.iterations)


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
    from ..data import build_training_source

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
    from ..compensation.wiener import tune_wiener_nsr
    from ..imaging.projection import project
    from ..metrics import ssim

    near_mm, far_mm = score_range_mm(cfg)
    depths_m = np.linspace(near_mm, far_mm, cfg.evaluation.wiener_tuning_depths) * 1e-3
    metric = ssim if cfg.evaluation.wiener_tuning_metric == "ssim" else "psnr"
    return tune_wiener_nsr(train_images, design.psf(depths_m), project, metric=metric)
