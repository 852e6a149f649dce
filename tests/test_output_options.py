"""Every output option of every command goes through the one output-over-input rule (issue 60,
items 1 and 2).

The commands' output options are found in their argparse definitions (the registry ``edofproj``
builds), not listed here: each is pointed at a file another option of the same command reads, and
into a training run's ``checkpoints/``, and must be refused with one line, exit 2, the file byte for
byte as it was. A help text that speaks of writing marks an output: an option whose help says so
but that the rule does not know fails :func:`test_every_option_that_writes_is_an_output_option`.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from edofproj.cli import OUTPUT_OPTIONS, OUTPUT_SPECS, READ_OPTIONS, build_parser, is_output_option, main
from edofproj.errors import EdofprojError
from edofproj.outputs import (
    CHECKPOINT_DIR,
    RUN_CONFIG_NAME,
    refuse_output_in_checkpoints,
    refuse_outputs_over_arguments,
)


def commands(parser=None, prefix=()):
    """``(command words, its parser)`` of every command of the registry."""
    parser = parser or build_parser()
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    if sub is None:
        yield prefix, parser
        return
    for name, child in sub.choices.items():
        yield from commands(child, (*prefix, name))


def option_name(action: argparse.Action) -> str:
    return action.option_strings[0] if action.option_strings else action.dest


COMMANDS = dict(commands())
OUTPUTS = [
    (words, action.dest)
    for words, parser in COMMANDS.items()
    for action in parser._actions
    if is_output_option(" ".join(words), action.dest) or action.dest in OUTPUT_SPECS
]
#: ``(command, option)`` whose help speaks of output but that name no file the command writes.
NOT_FILES = {
    ("export", "format"),  # the output's format
    ("compensate", "calib"),  # a calibration read, to invert the projector's response for the output
    ("procams evaluate", "targets"),  # the projector's output light they are: read
    ("summarize", "evaluations"),  # evaluate's output folders: read
    ("live", "camera"),  # a device spec (its commands write a capture the command then reads)
    ("procams capture", "camera"),
}


def test_the_registry_has_the_output_options_the_rule_checks():
    found = {(" ".join(words), dest) for words, dest in OUTPUTS}
    assert ("procams psf-map", "figure") in found and ("export", "out") in found and ("bench", "csv") in found
    assert ("finetune", "patch_psfs") not in found and ("procams estimate-psf", "patch_psfs") in found
    assert ("procams capture", "display") in found and ("live", "display") in found  # --display file:PATH
    assert {dest for _, dest in found} == set(OUTPUT_OPTIONS) | set(OUTPUT_SPECS)  # each name is some output
    assert all(
        " ".join(words) in {" ".join(w) for w in COMMANDS} for words, _ in [(c.split(), d) for c, d in READ_OPTIONS]
    )


def test_every_option_that_writes_is_an_output_option():
    writes = re.compile(r"\b(write|writes|output|destination)\b", re.IGNORECASE)
    missed = []
    for words, parser in COMMANDS.items():
        for action in parser._actions:
            command = " ".join(words)
            if action.nargs == 0 or action.type in (int, float) or (command, action.dest) in NOT_FILES:
                continue
            known = is_output_option(command, action.dest) or action.dest in OUTPUT_SPECS
            if writes.search(action.help or "") and not known:
                missed.append(f"{' '.join(words)} {option_name(action)}: {action.help}")
    assert not missed, missed


def _filler(action: argparse.Action, folder: Path) -> list[str]:
    """A value the parser accepts for a required ``action``: a choice, a number, or an existing file."""
    if action.choices:
        return [str(next(iter(action.choices)))]
    if action.type in (int, float):
        return ["1"]
    path = folder / f"in_{action.dest}.txt"
    path.write_text(f"an input of {action.dest}\n")
    return [str(path)]


def argv_with_output(words, dest: str, folder: Path, output_value) -> tuple[list[str], list[Path]]:
    """A command line of ``words`` that parses: its required options and one of each required group
    filled, the output ``dest`` given ``output_value(inputs)``, where ``inputs`` are the files the
    line names; returns the line and those files."""
    parser = COMMANDS[words]
    positionals, options, inputs = [], [], []
    chosen = {g._group_actions[0].dest for g in parser._mutually_exclusive_groups if g.required}
    reader = None  # an optional, plain-text option that is no output: names an input when nothing required does
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or action.dest == dest:
            continue
        if (action.required or action.dest in chosen) and is_output_option(" ".join(words), action.dest):
            options += [action.option_strings[0], str(folder / f"new_{action.dest}")]  # another output
            continue
        if action.required or action.dest in chosen:
            values = _filler(action, folder)
        elif (
            reader is None
            and action.option_strings
            and action.nargs is None
            and action.type is None
            and not action.choices
            and not is_output_option(" ".join(words), action.dest)
        ):
            reader = action
            continue
        else:
            continue
        if not action.choices and action.type not in (int, float):
            inputs.append(Path(values[0]))
        if action.option_strings:
            options += [action.option_strings[0], *values]
        else:
            positionals += values
    if not inputs:
        assert reader is not None, f"{words}: no option names an input"
        values = _filler(reader, folder)
        inputs.append(Path(values[0]))
        options += [reader.option_strings[0], *values]
    output = next(a for a in parser._actions if a.dest == dest)
    value = OUTPUT_SPECS.get(dest, "") + str(output_value(inputs))  # a device spec: file:PATH
    return [*words, *positionals, *options, output.option_strings[0], value], inputs


def _one_error_line(capsys, argv) -> str:
    capsys.readouterr()
    assert main(argv) == 2, argv
    lines = [line for line in capsys.readouterr().err.splitlines() if line and "warning:" not in line]
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: "), (argv, lines)
    return lines[0]


@pytest.mark.parametrize("words, dest", OUTPUTS, ids=[f"{' '.join(w)} {d}" for w, d in OUTPUTS])
def test_an_output_option_over_an_input_is_refused_before_the_command_runs(tmp_path, capsys, words, dest):
    argv, inputs = argv_with_output(words, dest, tmp_path, lambda inputs: inputs[0])
    before = {path: path.read_bytes() for path in inputs}
    line = _one_error_line(capsys, argv)
    assert "is the input" in line and str(inputs[0]) in line, line
    assert {path: path.read_bytes() for path in inputs} == before


@pytest.mark.parametrize("words, dest", OUTPUTS, ids=[f"{' '.join(w)} {d}" for w, d in OUTPUTS])
def test_no_output_option_writes_into_a_runs_checkpoints(tmp_path, capsys, words, dest):
    run = tmp_path / "run"
    (run / CHECKPOINT_DIR).mkdir(parents=True)
    (run / RUN_CONFIG_NAME).write_text("name: run\n")
    last = run / CHECKPOINT_DIR / "last.pt"
    last.write_bytes(b"the run's newest checkpoint")
    argv, _ = argv_with_output(words, dest, tmp_path, lambda inputs: last)
    line = _one_error_line(capsys, argv)
    assert "inside the checkpoints of the run" in line and "only training writes" in line, line
    assert last.read_bytes() == b"the run's newest checkpoint"


def test_the_run_layout_the_rule_knows_is_the_runs(tmp_path):
    from edofproj.runs import CHECKPOINT_DIR as RUNS_CHECKPOINT_DIR
    from edofproj.runs import CONFIG_NAME

    assert (CHECKPOINT_DIR, RUN_CONFIG_NAME) == (RUNS_CHECKPOINT_DIR, CONFIG_NAME)
    # a folder named checkpoints that is no run's may be written; a run's may not, nor below it
    (tmp_path / "checkpoints").mkdir()
    refuse_output_in_checkpoints(tmp_path / "checkpoints" / "x.pt")
    (tmp_path / RUN_CONFIG_NAME).write_text("name: run\n")
    for path in (tmp_path / "checkpoints", tmp_path / "checkpoints" / "sub" / "x.onnx"):
        with pytest.raises(EdofprojError, match="only training writes"):
            refuse_output_in_checkpoints(path, "--out")
    refuse_output_in_checkpoints(tmp_path / "net.onnx")


def test_two_outputs_of_one_file_are_refused(tmp_path):
    with pytest.raises(EdofprojError, match="--preview 'a.png' is also --out 'a.png'"):
        refuse_outputs_over_arguments([("--out", "a.png"), ("--preview", "a.png")], [])
    (tmp_path / "in.png").write_bytes(b"x")
    (tmp_path / "link.png").symlink_to(tmp_path / "in.png")
    with pytest.raises(EdofprojError, match="is the input --image"):  # another name of the same file
        refuse_outputs_over_arguments([("--out", tmp_path / "link.png")], [("--image", tmp_path / "in.png")])
    refuse_outputs_over_arguments([("--out", tmp_path / "new.png")], [("--image", tmp_path / "in.png")])


def test_export_into_the_runs_checkpoints_is_refused_and_the_checkpoint_kept(tmp_path, capsys):
    """The reported case: ``export RUN --out RUN/checkpoints/last.pt`` replaced the run's newest checkpoint."""
    import shutil

    from edofproj.builtin_runs import builtin_run_dir

    run = tmp_path / "run"
    shutil.copytree(builtin_run_dir("cpu-doe-net"), run)
    last = run / "checkpoints" / "last.pt"
    before = last.read_bytes()
    line = _one_error_line(capsys, ["export", str(run), "--format", "torchscript", "--out", str(last)])
    assert "inside the checkpoints of the run" in line, line
    assert last.read_bytes() == before and sorted(p.name for p in last.parent.iterdir()) == ["last.pt"]


def test_psf_map_figure_over_a_capture_of_the_lab_is_refused(tmp_path, capsys):
    """The reported case: ``procams psf-map ... --figure CAPTURE`` replaced the dot capture it reads
    (the capture is named by the lab manifest, not by an option)."""
    capture = tmp_path / "dots.png"
    cv2.imwrite(str(capture), np.full((24, 32, 3), 40, np.uint8))
    lab = {
        "format": "edofproj-lab",
        "version": 1,
        "projector": {"height": 24, "width": 32},
        "sequences": [
            {"name": "dots", "kind": "dots", "spacing_px": [8, 8], "origin_px": [0, 0], "files": {"list": ["dots.png"]}}
        ],
    }
    from edofproj.procams.lab_manifest import LAB_FORMAT

    lab["format"] = LAB_FORMAT
    (tmp_path / "lab.json").write_text(json.dumps(lab))
    (tmp_path / "map.npz").write_bytes(b"not read: refused before")
    before = capture.read_bytes()
    argv = [
        "procams",
        "psf-map",
        "--lab",
        str(tmp_path / "lab.json"),
        "--dots",
        "dots",
        "--map",
        str(tmp_path / "map.npz"),
    ]
    line = _one_error_line(capsys, [*argv, "--out", str(tmp_path / "p.npz"), "--figure", str(capture)])
    assert "--figure" in line and "is the input --lab's 'dots' capture" in line, line
    assert capture.read_bytes() == before and not (tmp_path / "p.npz").exists()
