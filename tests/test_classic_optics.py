"""Classic EDOF elements tuned by their blind linear filter (:mod:`edofproj.evaluation.classic_optics`,
``edofproj tune-classic``): candidates parsed with one-line errors, the element whose focal line
covers the scored range chosen over one that misses it, and the sweep's files."""

from __future__ import annotations

import csv

import pytest

from edofproj.cli import main
from edofproj.config import Config, apply_overrides
from edofproj.errors import EdofprojError
from edofproj.evaluation.classic_optics import current_candidate, parse_candidates
from edofproj.methods.catalogue import METHOD_NAMES, method_spec, select_methods
from tiny_configs import TINY_EVALUATION


def test_candidates_are_parsed_into_config_overrides():
    cubic = parse_candidates("cubic", "2.5, 10")
    assert [c.overrides for c in cubic] == [("doe.cubic_waves=2.5",), ("doe.cubic_waves=10",)]
    axicon = parse_candidates("axicon", "300:800,250:900")
    assert axicon[1].overrides == ("doe.axicon_near_mm=250", "doe.axicon_far_mm=900") and axicon[1].value == 650
    multifocal = parse_candidates("multifocal", "350/500/700;300/800")
    assert multifocal[0].overrides == ("doe.multifocal_foci_mm=[350,500,700]",) and multifocal[1].value == 2
    for overrides in (c.overrides for c in cubic + axicon + multifocal):
        apply_overrides(Config(), list(overrides))  # every override is a valid configuration key


@pytest.mark.parametrize(
    "kind, text, message",
    [
        ("cubic", "5,x", "'x' is not a number"),
        ("cubic", "-5", "must be > 0"),
        ("axicon", "800:300", "0 < near < far"),
        ("multifocal", "350/-1", "positive foci"),
        ("cubic", "5,5", "given twice"),
        ("lens", "1", "unknown classic element"),
    ],
)
def test_bad_candidates_are_one_line(kind, text, message):
    with pytest.raises(EdofprojError, match=message):
        parse_candidates(kind, text)


def test_the_classic_compensated_linear_baselines_are_scored_by_default_the_bare_elements_by_name():
    default = {spec.name for spec in select_methods(None)}
    for kind in ("cubic", "axicon", "multifocal"):
        assert {kind, f"{kind}+wiener", f"{kind}+ensemble"} <= set(METHOD_NAMES)
        assert {f"{kind}+wiener", f"{kind}+ensemble"} <= default and kind not in default
        assert method_spec(f"{kind}+ensemble").blind and not method_spec(f"{kind}+wiener").blind
    assert "doe+net" in default
    assert current_candidate(Config(), "axicon") == "300-800 mm"


@pytest.mark.slow
def test_an_axicon_focused_on_the_range_beats_one_focused_beyond_it(tmp_path, capsys):
    """Ground truth by construction: a focal line over the scored depths against one at 2-4 m."""
    argv = ["tune-classic", "--element", "axicon", "--values", "300:800,2000:4000", "--depths-mm", "300,550,800"]
    argv += ["--max-images", "2", "--out", str(tmp_path / "sweep"), "--quiet", "--config", "cpu"]
    for item in TINY_EVALUATION + ["psf.pupil_samples=512"]:  # the axicon's phase needs 512 samples
        argv += ["--set", item]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "chosen: 300-800 mm" in out
    with open(tmp_path / "sweep" / "classic_sweep.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 * 3 * 2 and {r["candidate"] for r in rows} == {"300-800 mm", "2000-4000 mm"}
    summary = (tmp_path / "sweep" / "classic_sweep.md").read_text()
    assert "**chosen**" in summary and "2000-4000 mm" in summary
    assert (tmp_path / "sweep" / "classic_sweep.png").stat().st_size > 0


def test_a_chosen_candidate_at_the_end_of_the_sweep_is_flagged():
    from edofproj.evaluation.classic_optics import ClassicSweep

    candidates = parse_candidates("cubic", "5,10,20")
    sweep = ClassicSweep("cubic", candidates, [300.0], ["a"], table=None)  # type: ignore[arg-type]
    sweep.summary = {"5 waves": (0.9, 0.8, 300.0), "10 waves": (0.8, 0.7, 300.0), "20 waves": (0.7, 0.6, 300.0)}
    assert sweep.chosen.label == "5 waves" and sweep.chosen_at_edge
    sweep.summary["10 waves"] = (0.95, 0.7, 300.0)
    assert sweep.chosen.label == "10 waves" and not sweep.chosen_at_edge
