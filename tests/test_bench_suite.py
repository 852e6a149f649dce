"""``benchmarks/suite.py``: the runner writes its format (every field, the CPU's instruction sets) from a
tiny case timed by a fake clock, and ``compare`` divides the right medians; nothing here depends on speed."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from edofproj.machine import instruction_sets

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "suite.py"


@pytest.fixture(scope="module")
def suite():
    spec = importlib.util.spec_from_file_location("bench_suite", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_suite"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules["bench_suite"]


class FakeClock:
    """Seconds that advance by the next of ``steps`` at each read (a call's duration is known exactly)."""

    def __init__(self, steps):
        self.now, self.steps = 0.0, list(steps)

    def __call__(self) -> float:
        self.now += self.steps.pop(0) if self.steps else 0.0
        return self.now


def tiny_case(suite, calls: list[int]):
    def run(ctx):
        wall, cpu = suite.timed(lambda: calls.append(1), ctx, warmup=1)
        return [suite.Measurement("call", wall, "ms", 1), suite.Measurement("call cpu", cpu, "ms", 1)]

    return suite.Case("tiny", "a call that appends to a list", run, 3)


def test_the_runner_writes_every_field_with_the_cpus_instruction_sets(suite, tmp_path):
    calls: list[int] = []
    # each timed call reads the wall clock twice: start then end; the durations are 5, 2 and 9 ms
    wall = FakeClock([0.0, 0.005, 0.0, 0.002, 0.0, 0.009])
    cpu = FakeClock([0.0, 0.001, 0.0, 0.001, 0.0, 0.004])
    machine = suite.Machine(
        commit="abc1234", date="2026-11-29T08:00:00+00:00", torch="2.13.0", isa=instruction_sets(), load1=lambda: 1.5
    )
    rows = suite.run_cases(
        ["tiny"], None, machine, {"tiny": tiny_case(suite, calls)}, {"clock": wall, "cpu_clock": cpu}
    )
    assert len(calls) == 1 + 3  # one warm-up, the case's default repeats
    out = tmp_path / "results.json"
    csv_path = suite.write_results(out, rows)
    data = json.loads(out.read_text())
    assert data["format"] == suite.FORMAT
    first = data["rows"][0]
    assert tuple(first) == suite.FIELDS
    assert first["case"] == "tiny" and first["metric"] == "call" and first["unit"] == "ms"
    assert first["repeats"] == 3 and first["threads"] == 1
    assert (
        first["median"] == pytest.approx(5.0)
        and first["value"] == pytest.approx(5.0)
        and first["min"] == pytest.approx(2.0)
    )
    assert data["rows"][1]["median"] == pytest.approx(1.0) and data["rows"][1]["min"] == pytest.approx(1.0)
    assert first["commit"] == "abc1234" and first["torch"] == "2.13.0" and first["load1"] == 1.5
    assert first["isa"] == instruction_sets() and first["isa"].split()[0]  # the machine, then its sets
    throughput = suite.rows_of("tiny", [suite.Measurement("frames/s", [2.5], "frames/s", 1, count=6)], machine, 0.0)
    assert throughput[0]["repeats"] == 6 and throughput[0]["median"] == 2.5  # one figure over 6 frames
    with open(csv_path, newline="") as handle:
        table = list(csv.DictReader(handle))
    assert tuple(table[0]) == suite.FIELDS
    assert [(r["case"], r["metric"], float(r["median"]), r["isa"]) for r in table] == [
        (r["case"], r["metric"], r["median"], r["isa"]) for r in data["rows"]
    ]


def known_rows(suite, medians: dict[tuple[str, str], float], commit: str) -> list[dict]:
    machine = suite.Machine(commit=commit, date="2026-11-29T08:00:00+00:00", torch="2.13.0", isa="x86_64 AVX2 FMA")
    rows = []
    for (case, metric), value in medians.items():
        rows += suite.rows_of(case, [suite.Measurement(metric, [value, 2 * value, value / 2], "ms", 2)], machine, 0.0)
    return rows


def test_compare_divides_new_by_base_per_case_and_metric_from_either_format(suite, tmp_path, capsys):
    base = known_rows(suite, {("a", "x"): 10.0, ("a", "y"): 4.0, ("gone", "x"): 1.0}, "base")
    new = known_rows(suite, {("a", "y"): 6.0, ("a", "x"): 5.0, ("added", "x"): 3.0}, "new")
    suite.write_results(tmp_path / "base.json", base)
    suite.write_results(tmp_path / "new.json", new)
    for b, n in (("base.json", "new.json"), ("base.csv", "new.csv"), ("base.json", "new.csv")):
        pairs = suite.compare_rows(suite.read_results(tmp_path / b), suite.read_results(tmp_path / n))
        assert [(c, m, r) for c, m, _, _, _, r in pairs] == [
            ("a", "y", pytest.approx(1.5)),
            ("a", "x", pytest.approx(0.5)),
        ]
    assert suite.main(["compare", str(tmp_path / "base.json"), str(tmp_path / "new.json")]) == 0
    printed = capsys.readouterr().out
    assert "| a | y | ms | 4 | 6 | 1.500 |" in printed and "| a | x | ms | 10 | 5 | 0.500 |" in printed
    assert "gone" not in printed and "added" not in printed


def test_bad_input_is_one_line_and_a_nonzero_exit(suite, tmp_path, capsys):
    (tmp_path / "junk.json").write_text("{}")
    assert suite.main(["compare", str(tmp_path / "junk.json"), str(tmp_path / "junk.json")]) == 2
    assert suite.main(["compare", str(tmp_path / "absent.json"), str(tmp_path / "junk.json")]) == 2
    assert suite.main(["--cases", "no-such-case"]) == 2
    assert suite.main(["--cases", "tiny", "--out", str(tmp_path / "r.txt")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 4 and all(line.startswith("suite.py: error: ") for line in errors)
    assert not (tmp_path / "r.txt").exists()


def test_demo_stages_are_cut_at_the_progress_events_that_begin_them(suite):
    """Each stage runs from its announcement to the next stage's (the last to the end); the progress lines
    between (the evaluation's own stages, notes) are inside the stage; CPU is cut the same way."""
    events = [
        ("plan: trains doe+net", 0.5, 0.1),
        ("stage 1/4 training", 1.0, 1.0),
        ("stage 2/4 evaluation", 11.0, 21.0),
        ("flat-screen sweep", 12.0, 23.0),
        ("stage 3/4 timing", 16.0, 30.0),
        ("scene sphere_wall", 17.0, 32.0),
        ("textured surface brick", 19.5, 36.0),
        ("stage 4/4 report", 20.0, 37.0),
    ]
    seconds = suite.demo_stage_seconds(events, (23.0, 40.0))
    assert seconds == {
        "training": (10.0, 20.0),
        "evaluation": (5.0, 9.0),
        "timing": (1.0, 2.0),
        "scene": (2.5, 4.0),
        "surface": (0.5, 1.0),
        "report": (3.0, 3.0),
        "total": (22.0, 39.0),
    }
    # a demo run without the timing stage: the evaluation ends where the scene begins
    without = suite.demo_stage_seconds([e for e in events if e[0] != "stage 3/4 timing"], (23.0, 40.0))
    assert "timing" not in without and without["evaluation"] == (6.0, 11.0)


def test_the_readme_table_is_read_and_a_demo_is_compared_with_it(suite):
    """The README's rows as printed (bold marks and worst depths dropped); a demo table whose per-depth means
    give doe+net's printed row exactly differs by 0, one moved by a known amount by that amount."""
    from edofproj.evaluation.results import MetricsTable

    rows = suite.readme_demo_rows(suite.README.read_text(encoding="utf-8"))
    assert len(rows) >= 10 and all(len(v) == 5 for v in rows.values())
    ours = rows["doe+net"]
    text = suite.README.read_text(encoding="utf-8")
    assert f"**{ours['ssim']:.4f}**" in text and f"**{ours['ssim_worst']:.4f}** (800)" in text

    def table(shift: float) -> MetricsTable:
        # two depths in range: the mean of their scores and the lower one give the row's mean and worst
        t = MetricsTable(("method", "depth_mm", "image"), ("psnr", "ssim", "de2000"))
        mean = {m: ours[m] for m in ("ssim", "psnr", "de2000")}
        worst = {"ssim": ours["ssim_worst"], "psnr": ours["psnr_worst"]}
        for depth, sign in ((300.0, -1), (800.0, 1)):
            values = {m: mean[m] for m in mean}
            values["ssim"] = worst["ssim"] if sign > 0 else 2 * mean["ssim"] - worst["ssim"]
            values["psnr"] = worst["psnr"] if sign < 0 else 2 * mean["psnr"] - worst["psnr"]
            values["ssim"] += shift
            t.add(method="doe+net", depth_mm=depth, image="a", **values)
        t.add(method="not-in-readme", depth_mm=300.0, image="a", psnr=1.0, ssim=0.0, de2000=9.0)
        return t

    exact = suite.demo_table_differences(table(0.0), (300.0, 800.0), rows)
    assert exact == pytest.approx({"ssim": 0.0, "psnr": 0.0, "de2000": 0.0}, abs=1e-12)
    moved = suite.demo_table_differences(table(0.003), (300.0, 800.0), rows)
    assert moved["ssim"] == pytest.approx(0.003) and moved["psnr"] == pytest.approx(0.0, abs=1e-12)
