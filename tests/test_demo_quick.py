"""``edofproj demo --quick`` end to end with tiny runs: two training processes, evaluation, timing, report."""

import csv
import math

import pytest

from edofproj.cli import main
from tiny_configs import TINY_EVALUATION

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess

#: Shrinks the quick demo further so that the test takes well under a minute.
TINY = TINY_EVALUATION + [
    "train.steps=3",
    "train.checkpoint_every=3",
    "evaluation.depths_mm=[300,500,800]",
    "evaluation.comparison_depths_mm=[320,800]",
    "net.linear_radius=15",  # the linear base's radius = the tiny psf.window (it mirrors the 32-px crops by it)
]


def test_quick_demo_writes_a_complete_report(tmp_path, capsys):
    out = tmp_path / "demo"
    args = ["demo", "--quick", "--quiet", "--out", str(out), "--methods", "lens,lens+wiener,lens+net,doe,doe+net"]
    for item in TINY:
        args += ["--set", item]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "report:" in printed and str(out / "report.html") in printed
    assert "claim (a) not judged (smoke run)" in printed and "claim (c) not judged (smoke run)" in printed
    assert "does not hold" not in printed
    assert "too small to judge any claim" in (out / "report.md").read_text()

    for run in ("doe_net", "lens_net"):
        assert (out / run / "checkpoints" / "last.pt").is_file()
    for name in ("report.html", "report.md", "summary.md", "metrics.csv", "tilted_metrics.csv"):
        assert (out / name).is_file(), name

    with open(out / "metrics.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        assert reader.fieldnames[:6] == ["method", "depth_mm", "image", "psnr", "ssim", "ms_ssim"]
        rows = list(reader)
    assert {r["method"] for r in rows} == {"lens", "lens+wiener", "lens+net", "doe", "doe+net"}
    for row in rows:
        assert math.isfinite(float(row["psnr"])) and 0.0 <= float(row["ms_ssim"]) <= 1.0
        assert -1.0 <= float(row["ssim"]) <= 1.0

    html = (out / "report.html").read_text()
    for section in (
        "Claims of the paper, on the evaluated images",
        "Summary",
        "Side-by-side comparison",
        "Tilted screen",
        "Optics",
        "Training",
        "Timing",
        "Projection onto a 3-D scene",
        "Projection onto a textured surface",
        "demo wall time",
    ):
        assert section in html, section
    # metric plots, comparison, tilted, PSF, DOE, training, scene x2, surface
    assert html.count("data:image/png;base64,") >= 10
    assert (out / "scene_metrics.csv").is_file() and (out / "surface_metrics.csv").is_file()
    surface_methods = {row["method"] for row in csv.DictReader(open(out / "surface_metrics.csv"))}
    assert {"doe+net", "doe+net+photometric", "lens+photometric"} <= surface_methods
    markdown = (out / "report.md").read_text()
    assert "(figures/eval_psf_lens_vs_doe.png)" in markdown and (out / "figures" / "eval_psf_lens_vs_doe.png").is_file()
    # three steps leave the quantized DOE flat: the report says why doe projects like lens
    assert "is still the flat plate it starts as (3 steps" in markdown


def test_demo_refuses_a_non_empty_output(tmp_path, capsys):
    (tmp_path / "old.txt").write_text("x")
    assert main(["demo", "--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not empty" in err


def test_demo_needs_our_method(tmp_path, capsys):
    assert main(["demo", "--quick", "--out", str(tmp_path / "d"), "--methods", "lens,lens+net"]) == 2
    assert "doe+net" in capsys.readouterr().err


def test_quick_demo_starts_from_the_shipped_reference_model(tmp_path, capsys):
    """``--pretrained``: doe_net/ is the built-in run (not trained again), evaluated with the demo's
    evaluation keys; lens+net is trained beside it; the compensated DOE beats the bare DOE."""
    from edofproj.runs import load_run

    out = tmp_path / "demo"
    args = ["demo", "--quick", "--quiet", "--pretrained", "--out", str(out), "--methods", "doe,doe+net,lens+net"]
    # the reference model has two phases: its baselines train the refit phase alone, with its network
    small = ["train.refit_steps=3", "train.refit_warmup_steps=1", "train.checkpoint_every=3", "refit_net.widths=[4,4]"]
    for item in [*small, "evaluation.depths_mm=[300,800]"]:
        args += ["--set", item]
    assert main(args) == 0
    capsys.readouterr()
    shipped, copied = load_run("builtin:cpu-doe-net"), load_run(out / "doe_net")
    assert copied.step == shipped.step > 3
    assert copied.cfg.evaluation.depths_mm == [300.0, 800.0] and copied.cfg.train == shipped.cfg.train
    assert load_run(out / "lens_net").step == 3
    report = (out / "report.md").read_text()
    assert "--pretrained" in report and "builtin:cpu-doe-net" in report and "pretrained" in report

    with open(out / "metrics.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    ssim = {}
    for row in rows:
        ssim.setdefault((row["method"], row["depth_mm"]), []).append(float(row["ssim"]))
    for depth in ("300", "800"):
        mean = {m: sum(ssim[(m, depth)]) / len(ssim[(m, depth)]) for m in ("doe", "doe+net")}
        assert mean["doe+net"] > mean["doe"] + 0.05, (depth, mean)
