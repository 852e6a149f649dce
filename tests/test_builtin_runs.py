"""Built-in runs: ``builtin:NAME`` wherever a run directory is, packaged without optimizer state,
never written into."""

import re
import shlex

import pytest
import torch

import edofproj.builtin_runs as builtin_runs
from edofproj.application.demo import recipe_difference
from edofproj.builtin_runs import builtin_names, package_run, resolve_run_dir
from edofproj.cli import main
from edofproj.config import load_config
from edofproj.errors import EdofprojError
from edofproj.runs import load_run, saved_config
from edofproj.training.trainer import train

SHIPPED = "builtin:cpu-doe-net"


def package_files() -> set:
    return {p for p in builtin_runs.ROOT.rglob("*") if p.is_file()}


def test_the_reference_model_ships_and_loads():
    assert SHIPPED in builtin_names()
    run = load_run(SHIPPED)
    assert run.run_dir == builtin_runs.ROOT / "cpu-doe-net"
    assert run.cfg.name == "cpu" and run.cfg.doe.kind == "mlp"
    assert run.step >= run.cfg.train.steps > 0  # the finished run, not an intermediate checkpoint
    checkpoint = torch.load(run.run_dir / "checkpoints" / "last.pt", weights_only=True)
    assert set(checkpoint) <= set(builtin_runs.KEPT_CHECKPOINT_KEYS) and "optimizer" not in checkpoint
    size_mb = sum(p.stat().st_size for p in run.run_dir.rglob("*") if p.is_file()) / 2**20
    assert size_mb < 5


def test_unknown_builtin_names_fail_with_the_list():
    with pytest.raises(EdofprojError, match="builtin:cpu-doe-net"):
        resolve_run_dir("builtin:no-such-run")
    assert str(resolve_run_dir("runs/x")) == "runs/x"  # a path stays a path


def test_packaging_a_run_keeps_what_loading_needs(tiny_config, tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    train(tiny_config("train.steps=3", "train.checkpoint_every=3"), run_dir, progress=False)
    monkeypatch.setattr(builtin_runs, "ROOT", tmp_path / "package")
    monkeypatch.setitem(builtin_runs.BUILTIN_RUNS, "tiny", "a test run")
    packaged = package_run(run_dir, "tiny", log_every=2)

    full = (run_dir / "checkpoints" / "last.pt").stat().st_size
    slim = (packaged / "checkpoints" / "last.pt").stat().st_size
    assert slim < full  # optimizer moments and random states dropped
    rows = (packaged / "train_log.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows] == ["step", "2", "3"]  # every 2nd step and the last

    original, shipped = load_run(run_dir), load_run("builtin:tiny")
    assert shipped.step == original.step == 3
    frame = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.equal(original.net(frame, frame), shipped.net(frame, frame))
    radius_m = torch.linspace(0, original.doe.aperture_radius_m, 257)
    assert torch.equal(original.doe.height_m(radius_m), shipped.doe.height_m(radius_m))


@pytest.mark.parametrize(
    "command",
    [
        ["evaluate", SHIPPED, "--methods", "doe"],
        ["export", SHIPPED, "--format", "torchscript"],
        ["tolerance", SHIPPED, "--trials", "1"],
    ],
)
def test_commands_never_write_into_a_builtin_run(command, capsys):
    before = package_files()
    assert main(command) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "built-in run" in err and "--out" in err
    assert package_files() == before


def test_a_builtin_run_is_named_wherever_a_run_is(tmp_path, capsys):
    out = tmp_path / "net.pt"
    assert main(["export", SHIPPED, "--format", "torchscript", "--out", str(out), "--no-verify"]) == 0
    assert out.is_file() and "step" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:  # a parse error, as for any bad argument
        main(["evaluate", "builtin:nope", "--out", str(tmp_path / "e")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "the built-in runs are " + ", ".join(builtin_runs.builtin_names()) in err
    assert "builtin:cpu-doe-net" in err


def test_builtin_runs_are_named_not_pathed_in_outputs(tmp_path, capsys, monkeypatch):
    """``export-doe builtin:NAME`` reports its source as builtin:NAME (not the package's path), and
    ``psf --plot`` labels the design builtin:NAME (not 'file')."""
    import edofproj.reporting.psf_plots as psf_plots

    out = tmp_path / "fab"
    assert main(["export-doe", SHIPPED, "--out", str(out), "--map-px", "512"]) == 0
    report = (out / "fab_report.md").read_text()
    assert f"Source: `{SHIPPED}`" in report and str(builtin_runs.ROOT) not in report
    assert str(builtin_runs.ROOT) not in (out / "fab_report.json").read_text()

    labels = []
    monkeypatch.setattr(psf_plots, "plot_psf_comparison", lambda panels, path: labels.extend(p[0] for p in panels))
    argv = ["psf", "--doe", SHIPPED, "--depth-mm", "400", "--window", "15", "--out", str(tmp_path / "p.npz")]
    assert main([*argv, "--plot", str(tmp_path / "p.png")]) == 0
    assert labels == ["lens", SHIPPED]


def test_run_labels():
    assert builtin_runs.run_label(builtin_runs.ROOT / "cpu-doe-net") == SHIPPED
    assert builtin_runs.run_label(builtin_runs.ROOT / "cpu-doe-net" / "doe.npz") == SHIPPED + "/doe.npz"
    assert builtin_runs.run_label("runs/mine") == "runs/mine"  # a user's path stays as given


@pytest.mark.parametrize("name", sorted(builtin_runs.BUILTIN_RUNS))
def test_every_builtin_run_has_a_complete_model_card(name):
    """A model card gives the command that trained the run and its scores, and keeps no placeholder
    (a line that is one upper-case word, such as a SCORES left to fill in)."""
    card = (builtin_runs.ROOT / name / "MODEL.md").read_text()
    assert "edofproj train" in card
    assert re.search(r"edofproj evaluate builtin:" + re.escape(name), card)
    assert re.search(r"\b0\.\d{4}\b", card), "no score in the card"
    placeholders = [line for line in card.splitlines() if re.fullmatch(r"\s*[A-Z_]{3,}\s*", line)]
    assert not placeholders, placeholders


def _card_training_command(card: str) -> list[str]:
    """The arguments of the first ``edofproj train`` command of a model card (continuation lines joined)."""
    text = card.replace("\\\n", " ")
    line = next(line for line in text.splitlines() if "edofproj train " in line)
    return shlex.split(line.split("edofproj train ", 1)[1])


@pytest.mark.parametrize("name", sorted(builtin_runs.BUILTIN_RUNS))
def test_every_model_cards_command_trains_its_runs_recipe_with_todays_presets(name):
    """The card's command, run today, would train the run's recipe: a preset that moved on (another network,
    other steps) must be pinned in the command (``--set``), or the card would not reproduce the run."""
    args = _card_training_command((builtin_runs.ROOT / name / "MODEL.md").read_text())
    config = args[args.index("--config") + 1]
    sets = [args[i + 1] for i, arg in enumerate(args) if arg == "--set"]
    if "--steps" in args:
        sets.append(f"train.steps={args[args.index('--steps') + 1]}")
    shipped = saved_config(builtin_runs.ROOT / name)
    assert recipe_difference(shipped, load_config(config, sets)) is None
