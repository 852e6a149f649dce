"""Training runs on disk: the run directory, its checkpoints, its training log and its figures.

    runs/<name>/
      config.yaml              the full resolved configuration of the run
      doe.npz                  the fabricated (quantized) DOE (:func:`edofproj.doe.save_doe`);
                               absent for a lens-only run
      checkpoints/last.pt      the newest checkpoint (+ step_XXXXXX.pt)
      train_log.csv            loss per step
      figures/                 loss curve, DOE profile, PSFs across depth

* :mod:`.directory` -- the layout, new-run and resume checks, :func:`load_run`;
* :mod:`.checkpoint` -- atomic checkpoints and random-generator state;
* :mod:`.log` -- ``train_log.csv``;
* :mod:`.figures` -- a run's figures;
* :mod:`.pack` -- a run as a few files of bounded size (to carry it off a leased machine) and back.
"""

from .directory import (
    CHECKPOINT_DIR,
    CONFIG_NAME,
    DOE_NAME,
    FIGURES_DIR,
    RESUMABLE_KEYS,
    TrainedRun,
    check_new_run_dir,
    check_resume_config,
    last_checkpoint_path,
    load_run,
    run_inputs,
    saved_config,
    with_absolute_paths,
    write_run_config,
)

__all__ = [
    "CHECKPOINT_DIR",
    "CONFIG_NAME",
    "DOE_NAME",
    "FIGURES_DIR",
    "RESUMABLE_KEYS",
    "TrainedRun",
    "check_new_run_dir",
    "run_inputs",
    "check_resume_config",
    "last_checkpoint_path",
    "load_run",
    "saved_config",
    "with_absolute_paths",
    "write_run_config",
]
