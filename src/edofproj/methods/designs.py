"""Optical designs under evaluation, and their PSFs across depth (computed once, cached).

An *optical design* is what sits in front of the projector: the bare lens, the evaluated run's
learned DOE, or the DOE of a baseline run (cubic phase plate, axicon). Every method of
:mod:`.methods` uses one design; methods that share a design share its PSFs

    p_z = PSF_design(z)        (n_depths, 3, K, K), each value the pixel's share of the pupil energy

simulated by the run's :func:`~edofproj.optics.psf_bank.simulator_from_config` (the radial engine
for radially symmetric designs, the 2-D engine otherwise). The 2-D engine costs seconds per
depth, so PSFs are cached per depth (rounded to 1 µm) and a design is never simulated twice
at the same depth.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
import torch

from ..errors import BlurExceedsWindowWarning
from ..optics.psf_bank import PSFBank, design_engine, simulator_from_config

#: Depths closer than this (metres) share one cache entry.
DEPTH_KEY_RESOLUTION_M = 1e-6


def _depth_key(depth_m: float) -> int:
    return int(round(float(depth_m) / DEPTH_KEY_RESOLUTION_M))


class OpticalDesign:
    """One design (``doe``, None for the bare lens) simulated with the optics of ``cfg``.

    ``design.psf(depths_m)`` -> float32 tensor ``(n, 3, K, K)`` on ``device`` (simulated on the
    CPU in the run's precision, then moved); ``design.bank(depths_m)`` -> a
    :class:`~edofproj.optics.psf_bank.PSFBank` on the CPU (for the PSF figures).
    """

    def __init__(self, key: str, label: str, doe, cfg, device: str | torch.device = "cpu") -> None:
        self.device = torch.device(device)
        self.key = key
        self.label = label
        self.doe = doe
        self.cfg = cfg
        self.engine = design_engine(doe, cfg.psf.engine)
        self._cache: dict[int, torch.Tensor] = {}

    @functools.cached_property
    def _simulator(self):
        """The PSF simulator, built on the first PSF asked for (its pixel integrals take a few hundred
        milliseconds): a method that never needs a PSF (a blind network given a capture) never builds it."""
        return simulator_from_config(self.cfg, engine=self.engine)

    @property
    def description(self) -> str:
        return self.doe.describe() if self.doe is not None else "bare lens (no DOE)"

    def psf(self, depths_m) -> torch.Tensor:
        """RGB PSFs ``(n, 3, K, K)`` float32 at ``depths_m`` (simulated on first use)."""
        depths = np.atleast_1d(np.asarray(depths_m, dtype=float))
        missing = sorted({_depth_key(z) for z in depths} - set(self._cache))
        if missing:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore", BlurExceedsWindowWarning)
                simulated = self._simulator(self.doe, np.array(missing) * DEPTH_KEY_RESOLUTION_M)
            for key, psf in zip(missing, simulated.float()):
                self._cache[key] = psf.to(self.device)
        return torch.stack([self._cache[_depth_key(z)] for z in depths])

    def bank(self, depths_m) -> PSFBank:
        depths = np.atleast_1d(np.asarray(depths_m, dtype=float))
        return PSFBank(
            psf=self.psf(depths).cpu(),
            depths_m=depths,
            pixel_pitch_m=self._simulator.geometry.pixel_pitch_m(depths),
            description=self.description,
        )
