"""The linear filter of the DOE being trained: the base of a safe network, and the yardstick of validation.

The depth-ensemble Wiener filter (:func:`~edofproj.compensation.wiener.depth_ensemble_wiener_kernel`)
of the *current* DOE's PSFs at :data:`~edofproj.compensation.linear_base.ENSEMBLE_DEPTHS` depths,
uniform in ``1/z`` over the scored range (``evaluation.score_range_mm``, else the PSF range): the
blind linear compensation ``doe+ensemble`` of the evaluation, with the NSR ``net.linear_nsr``.

For a jointly trained DOE the filter (and a multi-rate network's fixed linear path, cut to its
local filter's taps) follows the DOE: :func:`refresh_linear_base` recomputes it
(detached: no gradient flows through the filter into the DOE) before the first step and after
every ``train.linear_every`` steps and the last one. Simulating 32 depths and building the
kernel takes about 0.2 s on one CPU core with the ``cpu`` preset (about one training step), so
the default ``linear_every = 10`` adds about a tenth to the training time. A fixed DOE's filter is
computed once, before the first step.
"""

from __future__ import annotations

import warnings

import torch
from torch import nn

from ..compensation.linear_base import LinearBase, ensemble_depths_m
from ..compensation.wiener import depth_ensemble_wiener_kernel
from ..config import M_PER_MM, Config
from ..errors import BlurExceedsWindowWarning
from ..net_config import MultirateConfig
from .psf_table import DepthPSFTable


def scored_range_m(cfg: Config) -> tuple[float, float]:
    """``evaluation.score_range_mm`` in metres, or the PSF range when it is empty."""
    if cfg.evaluation.score_range_mm:
        near, far = cfg.evaluation.score_range_mm
        return float(near) * M_PER_MM, float(far) * M_PER_MM
    return cfg.psf.depth_min_m, cfg.psf.depth_max_m


@torch.no_grad()
def ensemble_psfs(cfg: Config, psf_source: nn.Module) -> torch.Tensor:
    """The current DOE's PSFs ``(N, C, K, K)`` at the ensemble depths of the scored range."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BlurExceedsWindowWarning)
        return psf_source(ensemble_depths_m(*scored_range_m(cfg)))


@torch.no_grad()
def current_linear_filter(cfg: Config, psf_source: nn.Module, into: LinearBase | None = None) -> LinearBase:
    """The depth-ensemble filter of the PSF source's current DOE, set into ``into`` (or a new
    :class:`LinearBase` of radius ``net.linear_radius``)."""
    psfs = ensemble_psfs(cfg, psf_source)
    linear = into if into is not None else LinearBase(psfs.shape[1], cfg.net.linear_radius)
    linear.set_from_psfs(psfs, cfg.net.linear_nsr)
    return linear


def refresh_linear_base(cfg: Config, net: nn.Module, psf_source: nn.Module) -> None:
    """Set a safe network's base filter to the current DOE's depth-ensemble filter, and a multi-rate
    network's fixed linear path (``net.linear_path: fixed``) for a DOE being trained to that filter
    cut to its ``(2 s + 1)^2`` taps (NSR ``net.init_nsr``); a no-op otherwise (a fixed DOE's multi-rate
    path is set once from its PSF table, :func:`~edofproj.training.trainer.start_from_wiener`)."""
    linear = getattr(net, "linear_base", None)
    if isinstance(linear, LinearBase):
        current_linear_filter(cfg, psf_source, into=linear)
    options = cfg.net
    if (
        isinstance(options, MultirateConfig)
        and options.linear_path == "fixed"
        and not isinstance(psf_source, DepthPSFTable)
    ):
        psfs = ensemble_psfs(cfg, psf_source).cpu().numpy()
        getattr(net, "initialize_linear_path")(
            depth_ensemble_wiener_kernel(psfs, options.init_nsr, radius=options.block_px)
        )


def refresh_due(cfg: Config, step: int) -> bool:
    """The filter is recomputed after step 0 (before training), every ``train.linear_every`` steps
    and after the run's last step, so that a resumed run (checkpoints hold the filter) matches an
    uninterrupted one."""
    return step % cfg.train.linear_every == 0 or step == cfg.train.steps
