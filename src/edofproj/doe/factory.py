"""Build a DOE from the configuration or from a ``--doe`` argument.

``--doe`` accepts a design name (``lens``, ``mlp``, ``free``, ``cubic``, ``axicon``,
``multifocal``), a saved design file (``.npz``) or a run directory holding ``doe.npz``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..builtin_runs import PREFIX, resolve_run_dir
from ..errors import EdofprojError
from ..optics.spectra import design_wavelength_nm
from .base import DOE
from .design_rules import apply_design_rules
from .designs import Axicon, CubicPhasePlate, LensOnly, Multifocal
from .mlp import FreeRadialDOE, RadialMLPDOE
from .storage import load_doe

DOE_CHOICES = ("lens", "mlp", "free", "cubic", "axicon", "multifocal")
RUN_DOE_FILE = "doe.npz"


def resolve_doe_file(spec: str) -> Path:
    """The DOE file named by ``spec``: a ``.npz`` file or a run directory containing ``doe.npz``
    (a path, or a built-in run ``builtin:NAME``)."""
    path = resolve_run_dir(spec)
    if path.is_dir():
        candidate = path / RUN_DOE_FILE
        if not candidate.is_file():
            raise EdofprojError(f"run directory '{spec}' has no {RUN_DOE_FILE} (a run without a DOE)")
        return candidate
    if path.is_file():
        return path
    raise EdofprojError(
        f"--doe '{spec}' is neither a design ({', '.join(DOE_CHOICES)}) nor an existing file or run directory"
    )


def design_label(spec: str) -> str:
    """The name a ``--doe`` design goes by in plots and reports: a design name as is, a built-in
    run as ``builtin:NAME``, a design file or run directory by its name (``runs/a/doe.npz`` -> ``doe``)."""
    if spec in DOE_CHOICES or spec.startswith(PREFIX):
        return spec
    return Path(spec.rstrip("/")).stem


def build_doe(cfg, spec: str | None = None) -> DOE:
    """A DOE for config ``cfg`` (a :class:`~edofproj.config.Config`); ``spec`` overrides ``cfg.doe.kind``."""
    doe_cfg = cfg.doe
    if spec is not None:
        if spec in DOE_CHOICES:
            doe_cfg = dataclasses.replace(doe_cfg, kind=spec)
        else:
            return load_doe(resolve_doe_file(spec))
    R = cfg.optics.aperture_m / 2
    v = cfg.optics.focus_m
    common = dict(
        aperture_radius_m=R,
        design_wavelength_m=design_wavelength_nm(cfg) * 1e-9,
        levels=doe_cfg.levels if doe_cfg.quantize else None,
        material=doe_cfg.material,
    )
    kind = doe_cfg.kind
    if kind == "lens":
        return LensOnly(R, common["design_wavelength_m"])
    if kind == "mlp":
        return RadialMLPDOE(
            **common,
            frequencies=doe_cfg.mlp_frequencies,
            hidden=doe_cfg.mlp_hidden,
            layers=doe_cfg.mlp_layers,
            clear_core_fraction=doe_cfg.clear_core_fraction,
        )
    if kind == "free":
        return FreeRadialDOE(
            **common, rings=max(cfg.psf.pupil_samples // 2, 1), clear_core_fraction=doe_cfg.clear_core_fraction
        )
    if kind == "cubic":
        return CubicPhasePlate(**common, alpha_waves=doe_cfg.cubic_waves)
    if kind == "axicon":
        return Axicon(**common, focus_distance_m=v, near_m=doe_cfg.axicon_near_m, far_m=doe_cfg.axicon_far_m)
    if kind == "multifocal":
        return Multifocal(**common, focus_distance_m=v, foci_m=doe_cfg.multifocal_foci_m)
    if kind == "file":
        return load_doe(resolve_doe_file(doe_cfg.path))
    raise EdofprojError(f"unknown DOE kind '{kind}' (known: {', '.join(DOE_CHOICES)}, or a file)")


def build_run_doe(cfg) -> DOE:
    """The configured DOE of a training run, with the design-for-manufacture rules applied when
    ``doe.min_feature_um > 0`` (:func:`edofproj.doe.design_rules.apply_design_rules`)."""
    doe = build_doe(cfg)
    if cfg.doe.min_feature_um > 0:
        doe = apply_design_rules(doe, cfg)
    return doe
