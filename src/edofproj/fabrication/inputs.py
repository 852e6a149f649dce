"""The input of the fabrication commands: a run directory (with ``doe.npz``) or a DOE design file.

For a run directory the run's own ``config.yaml`` (if present) is the configuration: an explicit
``--config`` is used only where it describes the run's projector, else refused with the keys that
differ (:func:`edofproj.config.config_on_run`); ``--set`` overrides apply last.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..builtin_runs import resolve_run_dir
from ..config import Config, config_on_run, load_config
from ..doe.factory import resolve_doe_file

RUN_CONFIG = "config.yaml"


@dataclass(frozen=True)
class DesignInput:
    """The design file and, when the input was a run, its run directory."""

    doe_file: Path
    run_dir: Path | None

    @classmethod
    def resolve(cls, spec: str) -> "DesignInput":
        doe_file = resolve_doe_file(spec)
        path = resolve_run_dir(spec)
        run_dir = path if path.is_dir() else None
        return cls(doe_file, run_dir)

    def config(self, config_arg: str | None = None, overrides=()) -> Config:
        if self.run_dir is not None and (self.run_dir / RUN_CONFIG).is_file():
            return config_on_run(self.run_dir / RUN_CONFIG, config_arg, list(overrides), f"the run '{self.run_dir}'")
        return load_config(config_arg, list(overrides))
