"""Monte Carlo tolerance analysis: how fabrication errors spread the PSF's energy concentration across depth.

Each trial draws one set of errors (:class:`.perturbation.FabricationErrors`: etch depth per
mask, overlay between masks, optionally decentre against the lens), builds the as-fabricated
DOE and simulates its RGB PSFs at the requested depths. The figure of merit is the
*energy concentration*

    E(z) = (1/C) sum_c sum_{3x3 centre pixels} PSF_c(z),

the fraction of the pupil energy that lands within the central 3 x 3 projector pixels,
averaged over the colour channels. PSFs are normalized by the pupil energy (not their own
sum), so a 3 x 3 simulation window gives E exactly.

Engines: ``radial`` (default) simulates the radial proxy of overlay errors on rings split at
every edge (:mod:`.ring_engine`: exact for sub-micrometre shifts); ``2d`` simulates true
lateral mask shifts and DOE decentre on the 2-D FFT engine (point-sampled on its grid;
much slower). Compensated image quality needs a trained network:
:func:`compensated_ssim_evaluator` builds ``evaluate_ssim(doe, depths_m) -> SSIM per depth``
from a run's network and held-out images (``edofproj tolerance RUN`` does this when the run
has a checkpoint): each as-fabricated DOE's PSFs (run window) blur the images, the network
compensates, the compensated input is projected, and SSIM is taken against the target.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import torch

from ..compensation.closed_loop import closed_loop, flat_screen
from ..errors import BlurExceedsWindowWarning, EdofprojError
from ..metrics import ssim
from ..optics.psf_bank import simulator_from_config
from .masks import decompose
from .perturbation import FabricatedDOE2D, FabricatedRadialDOE, FabricationErrors
from .profile import RadialProfile
from .ring_engine import radial_engine_on_edges

CONCENTRATION_BOX_PX = 3
PERCENTILES = (5.0, 50.0, 95.0)

SSIMEvaluator = Callable[[torch.nn.Module, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ToleranceSettings:
    """Error model and sampling of a tolerance run (lengths in micrometres as the CLI gives them)."""

    trials: int = 20
    etch_error_pct: float = 3.0
    misalignment_um: float = 0.5
    decentre_um: float = 0.0
    engine: str = "radial"
    seed: int = 0

    def validate(self) -> "ToleranceSettings":
        if self.trials < 1:
            raise EdofprojError(f"--trials {self.trials} must be >= 1")
        for name in ("etch_error_pct", "misalignment_um", "decentre_um"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise EdofprojError(f"--{name.replace('_', '-')} {value:g} must be >= 0")
        if self.engine not in ("radial", "2d"):
            raise EdofprojError(f"engine '{self.engine}' is not one of radial, 2d")
        if self.decentre_um > 0 and self.engine != "2d":
            raise EdofprojError("--decentre-um breaks radial symmetry: it needs --engine 2d")
        return self


@dataclass
class ToleranceResult:
    """Energy concentration (channel mean) of the nominal design (Z,) and of each trial (T, Z)."""

    depths_m: np.ndarray
    nominal: np.ndarray
    trials: np.ndarray
    nominal_per_channel: np.ndarray
    errors: list = field(default_factory=list)
    settings: ToleranceSettings = field(default_factory=ToleranceSettings)
    ssim_nominal: Optional[np.ndarray] = None
    ssim_trials: Optional[np.ndarray] = None

    def percentiles(self, values: np.ndarray | None = None) -> np.ndarray:
        """(3, Z): 5th, 50th and 95th percentile over trials."""
        return np.percentile(self.trials if values is None else values, PERCENTILES, axis=0)


def energy_concentration(psf: torch.Tensor, box_px: int = CONCENTRATION_BOX_PX) -> torch.Tensor:
    """Pupil-energy fraction within the central ``box_px`` x ``box_px`` pixels, (n_depths, C)."""
    K = psf.shape[-1]
    if box_px > K:
        raise EdofprojError(f"the PSF window ({K} px) is smaller than the {box_px}-px box")
    lo = K // 2 - box_px // 2
    return psf[..., lo : lo + box_px, lo : lo + box_px].sum(dim=(-1, -2))


class FabricatedPSF:
    """PSFs of as-fabricated DOEs for one config: builds the simulator once."""

    def __init__(self, cfg, engine: str = "radial", window: int = CONCENTRATION_BOX_PX):
        self.engine = engine
        self.sim = simulator_from_config(cfg, engine=engine, window=window)

    def doe(self, profile: RadialProfile, masks, errors: FabricationErrors):
        cls = FabricatedRadialDOE if self.engine == "radial" else FabricatedDOE2D
        return cls(profile, masks, errors)

    def __call__(self, doe, depths_m) -> torch.Tensor:
        sim = self.sim
        if isinstance(doe, FabricatedRadialDOE):
            sim = copy.copy(self.sim)
            sim.engine = radial_engine_on_edges(self.sim.engine, doe.edges_m())
        with torch.no_grad(), warnings.catch_warnings():
            # the haze outside the 3x3 box is irrelevant to the concentration
            warnings.simplefilter("ignore", BlurExceedsWindowWarning)
            return sim(doe, depths_m)


def compensated_ssim_evaluator(net, cfg, images: torch.Tensor, engine: str = "radial") -> SSIMEvaluator:
    """``evaluate_ssim(doe, depths_m)``: mean SSIM over ``images`` (B, 3, H, W) of
    ``project(net(I, project(I, P_z)), P_z)`` (the closed loop on a flat screen) against ``I``,
    for each depth ``z``."""

    psf_of = FabricatedPSF(cfg, engine, window=cfg.psf.window)

    def evaluate(doe, depths_m) -> np.ndarray:
        psf = psf_of(doe, depths_m).float()
        scores = []
        with torch.no_grad():
            for i in range(len(depths_m)):
                loop = closed_loop(images, flat_screen(psf[i : i + 1]), net)
                scores.append(float(ssim(loop.projected, images).mean()))
        return np.asarray(scores)

    return evaluate


def check_aperture(profile: RadialProfile, cfg) -> None:
    aperture_mm = 2 * profile.aperture_radius_m * 1e3
    if not math.isclose(aperture_mm, cfg.optics.aperture_mm, rel_tol=1e-6):
        raise EdofprojError(
            f"the design's aperture is {aperture_mm:g} mm but optics.aperture_mm={cfg.optics.aperture_mm:g}: "
            f"use --set optics.aperture_mm={aperture_mm:g}"
        )


def run_tolerance(
    profile: RadialProfile,
    cfg,
    settings: ToleranceSettings,
    depths_m,
    evaluate_ssim: SSIMEvaluator | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ToleranceResult:
    """Monte Carlo over fabrication errors (see the module docstring)."""
    settings.validate()
    check_aperture(profile, cfg)
    depths_m = np.atleast_1d(np.asarray(depths_m, dtype=float))
    masks = decompose(profile)
    psf_of = FabricatedPSF(cfg, settings.engine)
    rng = np.random.default_rng(settings.seed)

    nominal_doe = psf_of.doe(profile, masks, FabricationErrors.none(len(masks)))
    nominal_c = energy_concentration(psf_of(nominal_doe, depths_m)).double().cpu().numpy()
    ssim_nominal = None if evaluate_ssim is None else np.asarray(evaluate_ssim(nominal_doe, depths_m), dtype=float)
    trials, ssim_trials, drawn = [], [], []
    for t in range(settings.trials):
        errors = FabricationErrors.sample(
            rng, len(masks), settings.etch_error_pct, settings.misalignment_um * 1e-6, settings.decentre_um * 1e-6
        )
        doe = psf_of.doe(profile, masks, errors)
        trials.append(energy_concentration(psf_of(doe, depths_m)).double().cpu().numpy().mean(axis=1))
        if evaluate_ssim is not None:
            ssim_trials.append(np.asarray(evaluate_ssim(doe, depths_m), dtype=float))
        drawn.append(errors)
        if progress is not None:
            progress(t + 1, settings.trials)
    return ToleranceResult(
        depths_m=depths_m,
        nominal=nominal_c.mean(axis=1),
        trials=np.stack(trials),
        nominal_per_channel=nominal_c,
        errors=drawn,
        settings=settings,
        ssim_nominal=ssim_nominal,
        ssim_trials=np.stack(ssim_trials) if ssim_trials else None,
    )
