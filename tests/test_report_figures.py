"""What a reader of the report can read off it: every table column named, one colour per method in
every plot, a PSNR axis that a single exact depth does not stretch, image grids whose text is
readable at page width, captions that name the depths their figure shows."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import matplotlib.colors as mcolors
import numpy as np
import pytest

from edofproj.config import load_config
from edofproj.evaluation.results import MetricsTable
from edofproj.evaluation.surfaces import SurfaceEvaluation
from edofproj.evaluation.sweep import nearest_scored_depths_mm
from edofproj.methods.catalogue import METHOD_NAMES
from edofproj.reporting import figures, surfaces
from edofproj.reporting.document import Table
from edofproj.reporting.figures import PSNR_AXIS_MAX_DB, method_colour
from edofproj.reporting.image_checks import behind_linear_filter_blocks
from edofproj.reporting.writeup import psf_caption, psf_figure_depths_m

#: The width of a report page, in pixels, at which text must stay readable.
PAGE_PX = 800
READABLE_PX = 10


def saved_figures(monkeypatch) -> list:
    """The matplotlib figures the reporting functions save (their files are not written)."""
    kept: list = []

    def keep(fig, path, dpi=110):
        kept.append(fig)

    monkeypatch.setattr(figures, "_save", keep)
    return kept


def smallest_text_px_at_page_width(fig) -> float:
    """Height in pixels of the figure's smallest tile text (titles, axis labels) scaled to :data:`PAGE_PX`."""
    width_in = fig.get_size_inches()[0]
    sizes = []
    for ax in fig.axes:
        if not ax.images:
            continue
        for text in (ax.title, ax.xaxis.label, ax.yaxis.label):
            if text.get_text():
                sizes.append(text.get_fontsize())
    return min(sizes) / 72.0 * PAGE_PX / width_in


def test_every_report_table_names_every_column():
    with pytest.raises(ValueError, match="every column of a table has a name"):
        Table(["a", ""], [["1", "2"]])
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim", "de2000"))
    for method, value in (("doe+net", 0.9), ("doe+ensemble", 0.95)):
        for depth in (300.0, 800.0):
            table.add(method=method, depth_mm=depth, image="a", ssim=value, de2000=2.0)
    per_image = behind_linear_filter_blocks(table, (300.0, 800.0))[1]
    assert all(name.strip() for name in per_image.header)
    assert per_image.rows[0][-1] == "**yes**"  # the network is behind its filter on image a


def test_each_method_has_its_own_colour_in_every_plot():
    names = list(METHOD_NAMES) + [f"{m}+photometric" for m in ("lens", "lens+net", "doe", "doe+net")]
    colours = [mcolors.to_hex(method_colour(name)) for name in names]
    assert len(set(colours)) == len(colours), dict(zip(names, colours))
    assert mcolors.to_hex(method_colour("lens")) != mcolors.to_hex(method_colour("axicon+net"))  # were one blue
    assert mcolors.to_hex(method_colour("doe+net")) == "#000000"


def _depth_table(values: dict) -> MetricsTable:
    table = MetricsTable(("method", "depth_mm", "image"), ("psnr",))
    for method, by_depth in values.items():
        for depth, value in by_depth.items():
            table.add(method=method, depth_mm=depth, image="a", psnr=value)
    return table


def test_one_exact_depth_does_not_stretch_the_psnr_axis(monkeypatch, tmp_path):
    kept = saved_figures(monkeypatch)
    table = _depth_table(
        {"lens+cls": {300.0: 25.0, 500.0: 95.0, 800.0: 24.0}, "doe+net": {300.0: 27, 500.0: 28, 800.0: 26}}
    )
    figures.plot_metric_vs_depth(table, "psnr", tmp_path / "p.png", (300.0, 800.0))
    ax = kept[0].axes[0]
    assert ax.get_ylim()[1] == PSNR_AXIS_MAX_DB
    assert "clipped at 50 dB" in ax.get_title()
    assert any(text.get_text() == "95" for text in ax.texts)  # the clipped value is written
    kept.clear()
    figures.plot_metric_vs_depth(_depth_table({"doe+net": {300.0: 27, 800.0: 26}}), "psnr", tmp_path / "q.png")
    assert kept[0].axes[0].get_ylim()[1] < PSNR_AXIS_MAX_DB and "clipped" not in kept[0].axes[0].get_title()


def test_the_local_ssim_grid_wraps_and_its_text_is_readable(monkeypatch, tmp_path):
    kept = saved_figures(monkeypatch)
    methods = list(METHOD_NAMES)
    local = np.full((48, 64), 0.8)
    local[:4] = np.nan  # off the object
    examples = {("s", m): (np.zeros((48, 64, 3)), local, {"ssim": 0.8, "psnr": 20.0}) for m in methods}
    figures.plot_scene_ssim_maps(examples, ["s"], methods, tmp_path / "ssim.png")
    fig = kept[0]
    assert smallest_text_px_at_page_width(fig) >= READABLE_PX  # the strip of 11 tiles: about 4 px


def test_the_textured_surface_figure_wraps_and_its_text_is_readable(monkeypatch, tmp_path):
    kept: list = []
    monkeypatch.setattr(surfaces, "atomic_path", _no_file(kept))
    methods = ["lens", "lens+photometric", "lens+net", "lens+net+photometric", "doe", "doe+photometric", "doe+net",
               "doe+net+photometric"]  # fmt: skip
    table = MetricsTable(("method", "surface", "depth_mm", "image"), ("psnr", "ssim", "clipped"))
    for method in methods:
        for depth in (300.0, 500.0, 800.0):
            table.add(method=method, surface="brick", depth_mm=depth, image="a", psnr=20.0, ssim=0.6, clipped=0.0)
    tile = np.full((48, 64, 3), 0.5)
    examples = {("brick", name): tile for name in ["reflectance", "goal", *methods]}
    evaluation = SurfaceEvaluation(
        tmp_path, tmp_path, ["brick"], methods, table, (300.0, 800.0), 0.05, examples, example_depth_mm=300.0
    )
    surfaces.plot_surface_figure(evaluation, tmp_path / "s.png")
    assert smallest_text_px_at_page_width(kept[0]) >= READABLE_PX  # the strip of 11 panels: about 3 px


def _no_file(kept: list):
    """A stand-in for ``atomic_path`` that keeps the figure being saved instead of writing it."""
    import contextlib

    import matplotlib.pyplot as plt

    @contextlib.contextmanager
    def keep(path, suffix=""):
        kept.append(plt.gcf())
        yield Path(path).with_suffix(".unused.png")

    return keep


def test_the_comparison_rows_are_scored_depths():
    scored = [250.0, 300.0, 350.0, 400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0, 750.0, 800.0, 900.0]
    assert nearest_scored_depths_mm([320.0, 630.0, 800.0], scored) == [300.0, 650.0, 800.0]
    assert nearest_scored_depths_mm([320.0, 330.0], [300.0, 800.0]) == [300.0]  # one row, not two alike


def test_the_psf_caption_names_the_depths_its_figure_shows():
    cfg = load_config("cpu")
    shown_mm = psf_figure_depths_m(cfg) * 1e3
    caption = psf_caption(SimpleNamespace(cfg=cfg, range_mm=(300.0, 800.0)))
    assert f"{shown_mm[0]:.0f}" in caption and f"{shown_mm[-1]:.0f} mm" in caption
    assert caption.startswith("RGB PSFs at 275, ") and "the scores cover 300-800 mm" in caption


def _design_table() -> MetricsTable:
    """SSIM of methods of three designs at 250 (outside the scored range), 300 and 800 mm, one image."""
    ssim = {
        "lens": (0.99, 0.50, 0.60),
        "lens+net": (0.20, 0.70, 0.70),  # best blind lens method in range, worst at 250 mm (outside it)
        "lens+wiener": (0.90, 0.80, 0.82),
        "lens+cls": (0.95, 0.79, 0.81),
        "doe+ensemble": (0.60, 0.85, 0.86),
        "doe+net": (0.60, 0.88, 0.88),
        "doe+wiener": (0.60, 0.90, 0.91),
        "cubic+ensemble": (0.60, 0.75, 0.78),  # cubic: no non-blind method scored
    }
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    for method, values in ssim.items():
        for depth, value in zip((250.0, 300.0, 800.0), values):
            table.add(method=method, depth_mm=depth, image="a", ssim=value)
    return table


def test_each_design_is_drawn_with_its_best_blind_and_non_blind_method(monkeypatch, tmp_path):
    from edofproj.reporting.designs import best_compensations, designs_caption

    table = _design_table()
    best = best_compensations(table, (300.0, 800.0))
    assert [(b.design, b.kind, b.method) for b in best] == [
        ("lens", "blind", "lens+net"),  # the mean over 300-800 mm decides, not 250 mm
        ("lens", "non-blind", "lens+wiener"),
        ("doe", "blind", "doe+net"),
        ("doe", "non-blind", "doe+wiener"),
        ("cubic", "blind", "cubic+ensemble"),
    ]
    assert best[0].mean == pytest.approx(0.70) and best[3].mean == pytest.approx(0.905)
    caption = designs_caption(best, (300.0, 800.0))
    assert "bare lens: `lens+net` (blind, 0.700), `lens+wiener` (non-blind, 0.810)" in caption
    assert "cubic phase plate: `cubic+ensemble` (blind, 0.765), no non-blind method evaluated" in caption
    assert "axicon" not in caption and "300-800 mm" in caption

    kept = saved_figures(monkeypatch)
    figures.plot_designs_vs_depth(table, best, tmp_path / "designs.png", (300.0, 800.0))
    lines = {line.get_label(): line for line in kept[0].axes[0].get_lines()}
    assert set(lines) == {
        f"{label}: {b.method}"
        for b, label in zip(best, ["bare lens"] * 2 + ["learned DOE"] * 2 + ["cubic phase plate"])
    }
    styles = {
        label.split(": ")[1]: (mcolors.to_hex(line.get_color()), line.get_linestyle()) for label, line in lines.items()
    }
    assert styles["lens+net"][1] == "-" and styles["lens+wiener"][1] == "--"  # solid blind, dashed non-blind
    assert styles["lens+net"][0] == styles["lens+wiener"][0]  # one colour per design
    assert len({styles[m][0] for m in ("lens+net", "doe+net", "cubic+ensemble")}) == 3
    assert list(lines["bare lens: lens+net"].get_xdata()) == [250.0, 300.0, 800.0]  # every scored depth drawn
