"""Settings that cannot lie (issue 57): a stated accuracy belongs to the projector it was measured for,
a warm-up longer than its phase is refused, ``train`` says how long the run is phase by phase, and a
``--resume`` that changes the run's length says so."""

from __future__ import annotations

import warnings

import pytest

from edofproj.cli import main
from edofproj.config import load_config
from edofproj.errors import ConfigError, SpectralSamplingWarning

PICO = """base: cpu
optics:
  aperture_mm: 5.0
  throw_ratio: 1.2
  focus_mm: 1200.0
  width_px: 1920
  height_px: 1080
spectrum:
  peaks_nm: [625.0, 525.0, 455.0]
  fwhm_nm: [18.0, 40.0, 22.0]
psf:
  depth_min_mm: 800.0
  depth_max_mm: 2500.0
"""


def test_a_stated_accuracy_is_not_inherited_by_another_projector(tmp_path):
    path = tmp_path / "pico.yaml"
    path.write_text(PICO)
    assert load_config("cpu").spectrum.stated_l1_error == 0.009  # measured for the cpu preset's projector
    pico = load_config(str(path))
    assert pico.spectrum.stated_l1_error is None
    # the sampling check it silenced speaks again for this projector (its own LED spectra, 2 nodes per primary)
    from edofproj.optics.psf_bank import simulator_from_config

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        simulator_from_config(load_config(str(path), ["psf.pupil_samples=256"]))
    assert any(issubclass(w.category, SpectralSamplingWarning) for w in caught)
    # a config that states its own keeps it; one that changes nothing of the projector inherits it
    own = tmp_path / "own.yaml"
    own.write_text(
        PICO.replace("  fwhm_nm: [18.0, 40.0, 22.0]\n", "  fwhm_nm: [18.0, 40.0, 22.0]\n  stated_l1_error: 0.02\n")
    )
    assert load_config(str(own)).spectrum.stated_l1_error == 0.02
    same = tmp_path / "same.yaml"
    same.write_text("base: cpu\ntrain:\n  steps: 10\n")
    assert load_config(str(same)).spectrum.stated_l1_error == 0.009
    # --set on the projector drops it too, unless it is stated with them
    assert load_config("cpu", ["optics.width_px=1920"]).spectrum.stated_l1_error is None
    assert (
        load_config("cpu", ["optics.width_px=1920", "spectrum.stated_l1_error=0.01"]).spectrum.stated_l1_error == 0.01
    )


def test_a_stated_accuracy_can_be_cleared():
    assert load_config("cpu", ["spectrum.stated_l1_error=null"]).spectrum.stated_l1_error is None
    with pytest.raises(ConfigError, match="or null"):
        load_config("cpu", ["spectrum.stated_l1_error=1.5"])


def test_a_refit_warm_up_longer_than_its_phase_is_refused():
    with pytest.raises(ConfigError, match="longer than its phase"):
        load_config("cpu", ["train.refit_steps=200"])  # the preset's warm-up is 300 steps
    assert load_config("cpu", ["train.refit_steps=300"]).train.refit_steps == 300
    assert load_config("cpu", ["train.refit_steps=200", "train.refit_warmup_steps=60"]).train.refit_warmup_steps == 60


def test_train_says_how_long_each_phase_is():
    from edofproj.commands.train import describe_phases

    text = describe_phases(load_config("cpu", ["train.steps=2"]))
    assert text.startswith("1,002 steps: 2 joint + 1,000 refit")
    assert describe_phases(load_config("cpu", ["train.refit_steps=0", "train.steps=5"])).startswith("5 steps in one")


@pytest.mark.slow  # trains a tiny run twice
def test_resume_before_the_first_checkpoint_says_the_length_changes(tmp_path, tiny_config, capsys):
    """A run stopped before its first checkpoint, resumed with another config's lengths: said, not silent."""
    from edofproj.config import dump_config

    run = tmp_path / "run"
    short = tmp_path / "short.yaml"
    short.write_text(dump_config(tiny_config("train.steps=3", "train.checkpoint_every=100")))
    long = tmp_path / "long.yaml"
    long.write_text(dump_config(tiny_config("train.steps=4", "train.checkpoint_every=100")))
    assert main(["train", "--config", str(short), "--out", str(run), "--stop-after", "1", "--quiet"]) == 0
    for checkpoint in (run / "checkpoints").glob("*.pt"):
        checkpoint.unlink()  # as a run killed before its first checkpoint leaves it
    capsys.readouterr()
    assert main(["train", "--config", str(long), "--out", str(run), "--resume", "--stop-after", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "--resume changes the run's train.steps 3 -> 4" in out


def test_a_first_phase_warm_up_longer_than_the_phase_is_refused():
    """The realtime preset warms its learning rate up over 300 steps: 100 steps would end inside it."""
    with pytest.raises(ConfigError, match=r"train.warmup_steps=300 is longer than its phase, train.steps=100"):
        load_config("realtime", ["train.steps=100"])
    assert load_config("realtime", ["train.steps=100", "train.warmup_steps=10"]).train.warmup_steps == 10
