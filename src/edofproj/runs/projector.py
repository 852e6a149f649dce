"""One projector per run: the configuration with which a command simulates designs.

A run directory's ``config.yaml`` names the projector its DOE was designed for (lens, pixel grid,
throw ratio, spectra, PSF sampling and depth range: :data:`edofproj.config.PROJECTOR_SECTIONS`).
A command given a run -- or a design file -- simulates it with that projector, never the defaults:

* a run (a directory with ``config.yaml``, or ``builtin:NAME``): its saved configuration, with the
  command's ``--set`` overrides on top (deliberate changes, named key by key);
* ``--config C`` with a run: ``C`` only where it describes the same projector, else the command is
  refused with the keys that differ (:func:`edofproj.config.config_on_run`);
* two runs at once (``plot-psf --doe A --doe B``): they must share one projector;
* a design ``.npz`` file without a run: the configuration given (``--config``, else the defaults, with a
  :func:`warn_default_projector` saying so), refused when the file's aperture is not that configuration's
  (:func:`check_design_aperture`).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Iterable, Sequence

from ..builtin_runs import resolve_run_dir
from ..config import Config, config_on_run, describe_differences, load_config, projector_differences
from ..errors import EdofprojError, ProjectorWarning
from .directory import CONFIG_NAME, saved_config

#: Design names of ``--doe`` that are not files or runs (:data:`edofproj.doe.factory.DOE_CHOICES`).
_DESIGN_NAMES = ("lens", "mlp", "free", "cubic", "axicon", "multifocal")


def run_of(spec: str | None) -> Path | None:
    """The run directory ``spec`` names (a path holding ``config.yaml``, or ``builtin:NAME``), else None
    (a design name, a design file, or nothing)."""
    if spec is None or spec in _DESIGN_NAMES:
        return None
    try:
        path = resolve_run_dir(spec)
    except EdofprojError:
        return None
    return path if path.is_dir() and (path / CONFIG_NAME).is_file() else None


def config_for_designs(
    config_arg: str | None,
    overrides: Sequence[str],
    specs: Iterable[str | None],
    option: str = "--doe",
) -> Config:
    """The configuration with which a command simulates the designs ``specs`` (``--doe`` values: design
    names, design files, run directories): the run's own projector when one is a run (see the module),
    else ``config_arg`` (None: the defaults); ``overrides`` (``section.key=value``) apply last."""
    specs = list(specs)
    runs = [(spec, path) for spec in specs if (path := run_of(spec)) is not None]
    if not runs:
        return load_config(config_arg, list(overrides))
    first_spec, first_dir = runs[0]
    for spec, path in runs[1:]:
        differences = projector_differences(saved_config(first_dir), saved_config(path))
        if differences:
            raise EdofprojError(
                f"{option} '{first_spec}' and {option} '{spec}' were designed for different projectors "
                f"({describe_differences(differences)}): compare designs of one projector"
            )
    return config_on_run(first_dir / CONFIG_NAME, config_arg, list(overrides), f"the run {option} '{first_spec}'")


def warn_default_projector(spec: str | None, config_arg: str | None, option: str = "--doe") -> None:
    """A :class:`~edofproj.errors.ProjectorWarning` when ``spec`` is a design file (not a design name, not a run)
    simulated without ``--config``: the file holds its heights and aperture, not its projector. Called when the
    design is built, after the command's inputs have been read (a bad input fails in one line, alone)."""
    if config_arg is not None or spec is None or spec in _DESIGN_NAMES or run_of(spec) is not None:
        return
    warnings.warn(
        f"{option} '{spec}' is a design file, not a run: it is simulated with the default projector "
        "(aperture, focus, throw ratio, pixels, spectra); give --config of its projector, or its run directory",
        ProjectorWarning,
        stacklevel=2,
    )


def check_design_aperture(doe, cfg: Config, spec: str) -> None:
    """Refuse to simulate the design ``doe`` (loaded from ``spec``) behind an aperture that is not its own:
    a design file carries the aperture radius it was made for."""
    file_mm = 2e3 * float(doe.aperture_radius_m)
    if abs(file_mm - cfg.optics.aperture_mm) > 1e-6 * max(file_mm, cfg.optics.aperture_mm):
        raise EdofprojError(
            f"the design '{spec}' was made for a {file_mm:g} mm aperture, the configuration has "
            f"optics.aperture_mm={cfg.optics.aperture_mm:g}: give the --config of its projector (or its run directory)"
        )
