"""The evaluation's bookkeeping: metrics table statistics, the paper's claims, report rendering, scheduling."""

import math
import time
from pathlib import Path

import numpy as np
import pytest

from edofproj.application.schedule import ParallelTrainer, TrainingJob
from edofproj.errors import EdofprojError
from edofproj.evaluation.results import MetricsTable
from edofproj.methods.catalogue import (
    BASELINE_RUN_DIRS,
    CLASSIC_ELEMENTS,
    METHOD_NAMES,
    METHODS,
    method_spec,
    select_methods,
)
from edofproj.progress import StageProgress, format_duration
from edofproj.reporting.claims import ssim_claims, wall_time_claim
from edofproj.reporting.document import Figure, Heading, Paragraph, Report, Table
from edofproj.reporting.tables import format_text_table, image_spread_table, range_table, run_spread_table


def table_from(ssim_by_method: dict[str, dict[float, float]]) -> MetricsTable:
    """Two images per depth whose SSIMs average to the given value (PSNR derived from it)."""
    table = MetricsTable(("method", "depth_mm", "image"), ("psnr", "ssim", "ms_ssim"))
    for method, per_depth in ssim_by_method.items():
        for depth, value in per_depth.items():
            for image, offset in (("a", -0.01), ("b", 0.01)):
                table.add(
                    method=method, depth_mm=depth, image=image, psnr=20 + 10 * value, ssim=value + offset, ms_ssim=value
                )
    return table


def test_range_stats_are_mean_and_worst_of_the_per_depth_means():
    table = table_from({"lens": {250.0: 0.1, 300.0: 0.5, 500.0: 0.9, 800.0: 0.7, 900.0: 0.2}})
    stats = table.range_stats("lens", "ssim", 300, 800)
    assert stats.depths == 3
    assert stats.mean == pytest.approx((0.5 + 0.9 + 0.7) / 3)
    assert stats.worst == pytest.approx(0.5) and stats.worst_depth_mm == 300.0


def test_per_depth_means_are_the_means_of_the_selected_rows():
    # rows of two methods interleaved, a depth written as 300 and as 300.0000004 (the same depth within
    # 1e-6 mm), a method without rows at one depth, a NaN score: each mean is that of `values` at the depth
    rng = np.random.default_rng(3)
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    for image in "abc":
        for depth in (800.0, 300, 500.0, 300.0000004):
            for method in ("lens", "doe"):
                if method == "doe" and depth == 500.0:
                    continue
                table.add(method=method, depth_mm=depth, image=image, ssim=float(rng.random()))
    table.add(method="lens", depth_mm=800.0, image="d", ssim=math.nan)
    for method in ("lens", "doe"):
        means = table.per_depth_means(method, "ssim")
        expected = {
            z: float(table.values("ssim", method=method, depth_mm=z).mean())
            for z in table.depths_mm()
            if table.values("ssim", method=method, depth_mm=z).size
        }
        assert list(means) == list(expected)
        assert all(means[z] == expected[z] or math.isnan(means[z]) and math.isnan(expected[z]) for z in expected)
    assert 500.0 not in table.per_depth_means("doe", "ssim")
    assert math.isnan(table.per_depth_means("lens", "ssim")[800.0])


def test_worst_is_the_highest_value_for_lower_is_better_metrics():
    table = MetricsTable(("method", "depth_mm", "image"), ("lpips",))
    for depth, value in ((300.0, 0.4), (500.0, 0.1), (800.0, 0.3)):
        table.add(method="m", depth_mm=depth, image="x", lpips=value)
    stats = table.range_stats("m", "lpips", 300, 800)
    assert stats.worst == pytest.approx(0.4) and stats.worst_depth_mm == 300.0


def test_csv_round_trip(tmp_path):
    table = table_from({"lens": {300.0: 0.5}, "doe+net": {300.0: 0.8}})
    table.write_csv(tmp_path / "m.csv")
    back = MetricsTable.read_csv(tmp_path / "m.csv", ("method", "depth_mm", "image"))
    assert back.columns == table.columns and len(back.rows) == len(table.rows)
    assert back.mean("ssim", method="doe+net") == pytest.approx(0.8)


def test_csv_round_trip_keeps_nan_and_refuses_garbage(tmp_path):
    table = table_from({"lens": {300.0: float("nan")}})
    table.write_csv(tmp_path / "m.csv")
    back = MetricsTable.read_csv(tmp_path / "m.csv", ("method", "depth_mm", "image"))
    assert math.isnan(back.rows[0]["ssim"])
    (tmp_path / "bad.csv").write_text("method,depth_mm,image,ssim\nlens,300,x,oops\n")
    with pytest.raises(EdofprojError, match="line 2"):
        MetricsTable.read_csv(tmp_path / "bad.csv", ("method", "depth_mm", "image"))


def test_claims_hold_when_ours_wins_mean_and_worst():
    table = table_from(
        {
            "lens": {300.0: 0.5, 500.0: 0.99, 800.0: 0.7},
            "lens+cls": {300.0: 0.6, 500.0: 0.99, 800.0: 0.8},
            "doe+net": {300.0: 0.85, 500.0: 0.95, 800.0: 0.9},
        }
    )
    a, b = ssim_claims(table, (300, 800))
    assert a.holds and b.holds and a.verdict == "holds"


def test_claims_fail_plainly_when_a_baseline_wins():
    table = table_from(
        {"lens+cls": {300.0: 0.7, 500.0: 0.99, 800.0: 0.9}, "doe+net": {300.0: 0.8, 500.0: 0.9, 800.0: 0.85}}
    )
    a, b = ssim_claims(table, (300, 800))
    assert a.holds is False and a.verdict == "does not hold" and "lens+cls" in a.measured
    assert b.holds is True  # ours is worst at 0.8 > 0.7


def test_claims_are_not_measured_without_ours():
    a, b = ssim_claims(table_from({"lens": {300.0: 0.5}}), (300, 800))
    assert a.holds is None and b.holds is None and a.verdict == "not measured"


def test_wall_time_claim():
    assert wall_time_claim(899, 900).holds and not wall_time_claim(901, 900).holds


def test_range_table_marks_the_best_value_in_bold():
    table = table_from({"lens": {300.0: 0.5}, "doe+net": {300.0: 0.8}})
    rendered = range_table(table, (300, 800), ["ssim"])
    assert rendered.rows[1][2] == "**0.8000**" and rendered.rows[0][2] == "0.5000"
    assert "0.8000" in format_text_table(rendered) and "**" not in format_text_table(rendered)


def test_range_table_puts_blind_methods_first_and_bolds_the_best_of_each_group():
    table = table_from({"doe+wiener": {300.0: 0.9}, "lens": {300.0: 0.5}, "doe+net": {300.0: 0.8}})
    rendered = range_table(table, (300, 800), ["ssim"], frame_ms={"doe+net": 12.345, "lens": 0.01})
    assert [row[0] for row in rendered.rows] == ["lens", "doe+net", "doe+wiener"]
    assert [row[1] for row in rendered.rows] == ["blind", "blind", "PSF of each depth"]
    assert [row[2] for row in rendered.rows] == ["0.5000", "**0.8000**", "**0.9000**"]
    assert rendered.header[-1] == "ms/frame" and [row[-1] for row in rendered.rows] == ["0.01", "12.3", "-"]


def test_only_wiener_and_cls_are_non_blind():
    non_blind = {spec.name for spec in METHODS if not spec.blind}
    assert non_blind == {
        "lens+wiener",
        "lens+cls",
        "doe+wiener",
        "doe+cls",
        "cubic+wiener",
        "axicon+wiener",
        "multifocal+wiener",
    }


def test_method_registry():
    assert METHOD_NAMES == (
        "lens",
        "lens+wiener",
        "lens+cls",
        "lens+net",
        "lens+onlineprodeb",
        "doe",
        "doe+wiener",
        "doe+ensemble",
        "doe+net",
        "cubic+net",
        "axicon+net",
        "multifocal+net",
        "doe+cls",
        *(f"{kind}{suffix}" for kind in ("cubic", "axicon", "multifocal") for suffix in ("", "+wiener", "+ensemble")),
    )
    default = [
        *METHOD_NAMES[:11],
        *(f"{kind}{suffix}" for kind in CLASSIC_ELEMENTS for suffix in ("+wiener", "+ensemble")),
    ]
    assert [s.name for s in select_methods(None)] == default  # scored by default
    assert [method_spec(name).design for name in ("lens+onlineprodeb", "doe+ensemble", "cubic+net", "axicon")] == [
        "lens",
        "doe",
        "cubic",
        "axicon",
    ]
    assert set(BASELINE_RUN_DIRS) == {"lens+net", "lens+onlineprodeb", "cubic+net", "axicon+net", "multifocal+net"}
    assert [s.name for s in select_methods(["doe+net", "lens"])] == ["lens", "doe+net"]  # canonical order
    with pytest.raises(EdofprojError, match="known: lens, lens\\+wiener"):
        method_spec("wiener")


def tiny_png(path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, np.random.default_rng(0).random((8, 8, 3)))
    return path


def test_html_is_self_contained_and_markdown_links_files(tmp_path):
    (tmp_path / "figures").mkdir()
    figure = tiny_png(tmp_path / "figures" / "f.png")
    report = Report("T <1>")
    report.extend(
        [
            Heading("Section"),
            Paragraph("a **bold** & <tag> PASS"),
            Table(["m", "x"], [["a", "1.0"]]),
            Figure(figure, "caption"),
        ]
    )
    report.write(tmp_path / "r.md", tmp_path / "r.html")
    html = (tmp_path / "r.html").read_text()
    assert "data:image/png;base64," in html and "figures/f.png" not in html
    assert "<b>bold</b>" in html and "&amp; &lt;tag&gt;" in html and 'class="pass"' in html
    markdown = (tmp_path / "r.md").read_text()
    assert "![caption](figures/f.png)" in markdown and "| a | 1.0 |" in markdown and "|---|---:|" in markdown


def test_format_duration():
    assert (
        format_duration(75) == "01:15" and format_duration(3725) == "1:02:05" and format_duration(math.nan) == "--:--"
    )


def test_scheduler_skips_optional_jobs_that_cannot_fit(tmp_path):
    progress = StageProgress("test", enabled=False)
    jobs = [
        TrainingJob("doe+net", tmp_path / "a", [], steps=100, required=True),
        TrainingJob("axicon+net", tmp_path / "b", [], steps=100, required=False, relative_cost=1.0, setup_s=5),
        TrainingJob("lens+onlineprodeb", tmp_path / "c", [], steps=100, required=False, relative_cost=7.0),
    ]
    # 0.6 s/step: axicon needs 65 s, OnlineProDeb 435 s; 100 s are left
    trainer = ParallelTrainer(
        jobs,
        "cpu",
        tmp_path / "logs",
        workers=2,
        deadline=time.perf_counter() + 100,
        progress=progress,
        default_rate_s=0.6,
    )
    assert trainer.next_job() is jobs[0]
    jobs[0].status = "running"
    assert trainer.next_job() is jobs[1]
    jobs[1].status = "running"
    assert trainer.next_job() is None
    assert jobs[2].status == "skipped" and "time budget" in jobs[2].note


def test_image_spread_table_gives_the_spread_over_images_and_the_paired_difference():
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    values = {"doe+net": {"a": (0.9, 0.8), "b": (0.7, 0.7)}, "doe+wiener": {"a": (0.8, 0.8), "b": (0.75, 0.75)}}
    for method, images in values.items():
        for image, (near, far) in images.items():
            table.add(method=method, depth_mm=300.0, image=image, ssim=near)
            table.add(method=method, depth_mm=800.0, image=image, ssim=far)
            table.add(method=method, depth_mm=900.0, image=image, ssim=0.0)  # outside the range
    rows = {row[0]: row for row in image_spread_table(table, (300, 800)).rows}
    # doe+net per image: a 0.85, b 0.70 -> mean 0.775, sd |0.85 - 0.70| / sqrt(2)
    assert rows["doe+net"][1] == f"0.7750 ± {0.15 / math.sqrt(2):.4f}" and rows["doe+net"][2] == "0.7000 (b)"
    # differences a: +0.05, b: -0.05 -> mean 0, sd 0.0707, better on 1 of 2
    assert rows["doe+wiener"][3] == f"+0.0000 ± {0.1 / math.sqrt(2):.4f} (1/2)"


def _two_depth_table(values: dict) -> MetricsTable:
    """``values[method] = (ssim at 300 mm, ssim at 800 mm)`` for one image, plus a depth outside the range."""
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    for method, (near, far) in values.items():
        table.add(method=method, depth_mm=300.0, image="a", ssim=near)
        table.add(method=method, depth_mm=800.0, image="a", ssim=far)
        table.add(method=method, depth_mm=900.0, image="a", ssim=0.0)
    return table


def test_run_spread_table_gives_the_spread_over_runs_and_the_paired_difference():
    runs = {
        "seed0": _two_depth_table({"doe+net": (0.9, 0.8), "doe+wiener": (0.8, 0.8)}),
        "seed1": _two_depth_table({"doe+net": (0.7, 0.7), "doe+wiener": (0.8, 0.7)}),
    }
    rows = {row[0]: row for row in run_spread_table(runs, (300, 800)).rows}
    # doe+net: means 0.85 and 0.70 (sd 0.15/sqrt 2); worst depths 0.8 and 0.7 (sd 0.1/sqrt 2)
    assert rows["doe+net"][1:5] == [
        "blind",
        "2",
        f"0.7750 ± {0.15 / math.sqrt(2):.4f}",
        f"0.7500 ± {0.1 / math.sqrt(2):.4f}",
    ]
    # doe+wiener: means 0.80 and 0.75; doe+net minus it: +0.05 and -0.05, better in 1 of 2 runs
    assert rows["doe+wiener"][1] == "non-blind" and rows["doe+wiener"][3] == f"0.7750 ± {0.05 / math.sqrt(2):.4f}"
    assert rows["doe+wiener"][5] == f"+0.0000 ± {0.1 / math.sqrt(2):.4f} (1/2)"
    assert rows["doe+wiener"][6] == "+0.0000 ± 0.0000 (0/2)"  # worst depths 0.8 and 0.7 for both
    # LPIPS: lower is better, so doe+net's lower values count as better runs
    lpips_table = MetricsTable(("method", "depth_mm", "image"), ("lpips",))
    for method, value in (("doe+net", 0.2), ("doe", 0.5)):
        for depth in (300.0, 800.0):
            lpips_table.add(method=method, depth_mm=depth, image="a", lpips=value)
    lpips_rows = {row[0]: row for row in run_spread_table({"seed0": lpips_table}, (300, 800), metric="lpips").rows}
    assert lpips_rows["doe"][5:] == ["-0.3000 (1/1)", "-0.3000 (1/1)"]
    one = run_spread_table({"seed0": runs["seed0"]}, (300, 800)).rows
    assert one[0][3] == "0.8500" and one[1][5] == "+0.0500 (1/1)"  # one run: no spread shown


def test_summarize_prints_the_spread_of_evaluations_and_refuses_unlike_ones(tmp_path, capsys):
    from edofproj.cli import main

    for seed, near in (("s0", 0.9), ("s1", 0.7)):
        (tmp_path / seed).mkdir()
        _two_depth_table({"doe+net": (near, 0.8), "doe": (0.5, 0.5)}).write_csv(tmp_path / seed / "metrics.csv")
    assert main(["summarize", str(tmp_path / "s0"), str(tmp_path / "s1")]) == 0
    printed = capsys.readouterr().out
    assert f"| doe+net | blind | 2 | 0.8000 ± {0.1 / math.sqrt(2):.4f} |" in printed  # means 0.85, 0.75

    other = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    other.add(method="doe+net", depth_mm=300.0, image="b", ssim=0.5)
    other.write_csv(tmp_path / "other.csv")
    for args, message in (
        ([str(tmp_path / "s0"), str(tmp_path / "other.csv")], "other images"),
        ([str(tmp_path / "s0"), str(tmp_path / "missing")], "no metrics.csv"),
        ([str(tmp_path / "s0"), "--range-mm", "800"], "NEAR:FAR"),
        ([str(tmp_path / "s0"), "--metric", "lpips"], "no lpips column"),
    ):
        assert main(["summarize", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err


def test_a_method_left_out_is_named_once_in_the_notes():
    """The demo notes 'cubic+net not evaluated: ...' and the builder 'axicon+net skipped: ...'; the list of
    methods not evaluated names only the others, so no method is reported twice (issue 29)."""
    from types import SimpleNamespace

    from edofproj.reporting.document import Bullets
    from edofproj.reporting.writeup import methods_section

    evaluated = [SimpleNamespace(name=n, spec=method_spec(n), detail="") for n in ("doe", "doe+net")]
    ev = SimpleNamespace(
        methods=evaluated,
        notes=["cubic+net not evaluated: the time budget", "axicon+net skipped: no trained run at 'x'"],
        perceptual_missing=[],
        frame_ms={},
    )
    notes = next(block for block in methods_section(ev)[2:] if isinstance(block, Bullets)).items
    text = "\n".join(notes)
    assert text.count("cubic+net") == 1 and text.count("axicon+net") == 1
    listed = next(n for n in notes if n.startswith("Not evaluated:"))
    others = [m for m in METHOD_NAMES if m not in ("doe", "doe+net", "cubic+net", "axicon+net")]
    assert listed == f"Not evaluated: {', '.join(others)}."


def test_the_demo_timing_table_says_how_it_differs_from_the_summary_ms_per_frame():
    from edofproj.application.demo import timing_section
    from edofproj.evaluation.timing import Timing

    blocks = timing_section([Timing("doe+net", "torch", "cpu", 128, 128, 887.9, 2)], 2, (256, 256))
    paragraph = next(b for b in blocks if isinstance(b, Paragraph)).text
    assert "not the summary's ms/frame" in paragraph and "(256x256 frames)" in paragraph
    table = next(b for b in blocks if isinstance(b, Table))
    assert table.header[-1] == "128x128" and table.rows == [["doe+net", "torch", "887.9"]]


def test_comparison_labels_are_readable_at_page_width(tmp_path):
    """Ten methods at one depth: the P/S labels on the tiles are at least 10 px high when the
    figure is shown 800 px wide (a report page), measured on the written PNG (issue 29)."""
    from PIL import Image

    from edofproj.reporting import figures

    target = np.random.default_rng(0).random((48, 64, 3))
    methods = [m for m in METHOD_NAMES if m != "cubic+net"]
    examples = {(320.0, m): (target, {"psnr": 20.0 + i, "ssim": 0.5}) for i, m in enumerate(methods)}
    path = tmp_path / "comparison.png"
    figures.plot_comparison(target, examples, [320], methods, path)
    width_px = Image.open(path).size[0]
    label_px = figures.TILE_FONT_PT / 72 * figures.GRID_DPI * min(1.0, 800 / width_px)
    assert label_px >= 10, (width_px, label_px)


def test_training_curves_draw_each_run_in_its_own_panel(tmp_path, monkeypatch):
    """Two runs with the same losses step for step: each still has its own visible curve (issue 29)."""
    from edofproj.reporting import figures

    drawn = {}
    monkeypatch.setattr(figures, "_save", lambda fig, path, dpi=110: drawn.setdefault("fig", fig))
    rows = [{"step": s, "loss": 1.0 / s} for s in range(1, 41)]
    figures.plot_training_curves([("doe+net", rows), ("lens+net", rows), ("axicon+net", rows[:20])], tmp_path / "c.png")
    panels = [ax for ax in drawn["fig"].axes if ax.get_title()]
    assert [ax.get_title() for ax in panels] == ["doe+net", "lens+net", "axicon+net"]
    for ax in panels:  # the panel's own run, in colour and on top of the grey ones
        coloured = [line for line in ax.get_lines() if line.get_color() not in ("0.75",) and line.get_alpha() is None]
        assert len(coloured) == 1 and coloured[0].get_zorder() >= max(line.get_zorder() for line in ax.get_lines())
