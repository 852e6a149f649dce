"""End to end: ``edofproj evaluate`` and ``edofproj compensate`` on tiny runs trained here (a few seconds)."""

import csv
import math
import re

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.config import load_config
from edofproj.evaluation.results import BASE_METRICS
from edofproj.evaluation.sweep import PERCEPTUAL_COLUMNS, load_perceptual_metrics
from edofproj.imaging.image_io import read_image, write_image
from tiny_configs import TINY_EVALUATION

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess

#: A tiny but physically valid setup: 384 pupil samples resolve the defocus phase at 300 mm.
TINY = TINY_EVALUATION
METHODS = "lens,lens+wiener,lens+cls,lens+net,doe,doe+wiener,doe+ensemble,doe+net"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """``<root>/doe_net`` (joint) and ``<root>/lens_net`` (its lens-only baseline), 2 steps each."""
    from edofproj.training.trainer import train

    root = tmp_path_factory.mktemp("runs")
    train(load_config(None, TINY), root / "doe_net", progress=False)
    train(load_config(None, TINY + ["doe.kind=lens"]), root / "lens_net", progress=False)
    return root


@pytest.fixture(scope="module")
def evaluated(runs):
    code = main(["evaluate", str(runs / "doe_net"), "--methods", METHODS, "--quiet"])
    assert code == 0
    return runs / "doe_net"


def read_rows(path):
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        return reader.fieldnames, list(reader)


def test_evaluate_writes_every_file(evaluated):
    for name in ("metrics.csv", "tilted_metrics.csv", "summary.md", "report.md", "report.html"):
        assert (evaluated / name).is_file(), name
    for name in (
        "eval_ssim_vs_depth.png",
        "eval_psnr_vs_depth.png",
        "eval_comparison.png",
        "eval_tilted.png",
        "eval_psf_lens_vs_doe.png",
        "eval_doe_profile.png",
        "eval_training_curves.png",
    ):
        assert (evaluated / "figures" / name).stat().st_size > 1000, name
    html = (evaluated / "report.html").read_text()
    assert "data:image/png;base64," in html and 'src="figures/' not in html
    summary = (evaluated / "summary.md").read_text()
    assert "ms/frame" in summary and "PSF of each depth" in summary and "sd over images" in summary
    assert "](figures/eval_comparison.png)" in (evaluated / "report.md").read_text()


def test_metrics_csv_columns_and_values(evaluated):
    header, rows = read_rows(evaluated / "metrics.csv")
    available = [c for c in PERCEPTUAL_COLUMNS if c in load_perceptual_metrics()]
    assert header == ["method", "depth_mm", "image", *BASE_METRICS, *available]  # never a column of zeros
    assert {r["method"] for r in rows} == set(METHODS.split(","))
    assert {float(r["depth_mm"]) for r in rows} == {300.0, 500.0}
    assert len(rows) == len(METHODS.split(",")) * 2 * 2  # methods x depths x images
    for row in rows:
        psnr, ssim, ms_ssim = float(row["psnr"]), float(row["ssim"]), float(row["ms_ssim"])
        assert math.isfinite(psnr) and psnr > 5
        assert -1.0 <= ssim <= 1.0 and 0.0 <= ms_ssim <= 1.0
    _, tilted = read_rows(evaluated / "tilted_metrics.csv")
    assert {r["method"] for r in tilted} == set(METHODS.split(","))
    # the tilted screen spans the scored range (here the training range, 300-800 mm)
    assert all(float(r["near_mm"]) == 300.0 and float(r["far_mm"]) == 800.0 for r in tilted)


def test_lens_is_sharper_in_focus_than_at_300_mm(evaluated):
    _, rows = read_rows(evaluated / "metrics.csv")
    lens = {(float(r["depth_mm"]), r["image"]): r for r in rows if r["method"] == "lens"}
    for image in {key[1] for key in lens}:
        in_focus, near = lens[(500.0, image)], lens[(300.0, image)]
        assert float(in_focus["ssim"]) > float(near["ssim"]) + 0.1
        assert float(in_focus["psnr"]) > float(near["psnr"]) + 5


def test_known_psf_compensation_beats_no_compensation_at_300_mm(evaluated):
    _, rows = read_rows(evaluated / "metrics.csv")

    def mean_ssim(method):
        return np.mean([float(r["ssim"]) for r in rows if r["method"] == method and float(r["depth_mm"]) == 300])

    assert mean_ssim("lens+wiener") > mean_ssim("lens")
    assert mean_ssim("lens+cls") > mean_ssim("lens")


def test_summary_mentions_skipped_and_unavailable(runs, tmp_path):
    out = tmp_path / "ev"
    assert (
        main(
            [
                "evaluate",
                str(runs / "doe_net"),
                "--methods",
                "lens,doe+net",
                "--out",
                str(out),
                "--quiet",
                "--depths-mm",
                "300",
            ]
        )
        == 0
    )
    summary = (out / "summary.md").read_text()
    assert "Not evaluated:" in summary and "cubic+net" in summary
    if not load_perceptual_metrics():
        assert "unavailable" in summary


def test_missing_baseline_is_a_note_unless_requested(runs, tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["evaluate", str(runs / "doe_net"), "--out", str(out), "--quiet", "--depths-mm", "500"]) == 0
    err = capsys.readouterr().err
    assert "axicon+net skipped" in err
    # a classic element its pupil sampling cannot resolve is a note too (the tiny run's 384 samples)
    assert "cubic+wiener skipped: pupil_samples=384 cannot resolve the cubic phase" in err
    evaluated = {row["method"] for row in read_rows(out / "metrics.csv")[1]}
    assert "cubic+wiener" not in evaluated and {"lens", "doe+net"} <= evaluated
    code = main(["evaluate", str(runs / "doe_net"), "--methods", "axicon+net", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "axicon_net" in err
    code = main(
        ["evaluate", str(runs / "doe_net"), "--methods", "cubic+wiener", "--quiet", "--out", str(tmp_path / "c")]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "pupil_samples=384 cannot resolve" in err  # asked by name


def test_unknown_method_is_one_line_listing_the_known_ones(runs, capsys):
    assert main(["evaluate", str(runs / "doe_net"), "--methods", "lens,doe+magic"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "doe+magic" in err and "lens+wiener" in err and "axicon+net" in err


def test_run_without_checkpoint_is_one_line(tmp_path, capsys):
    run = tmp_path / "empty_run"
    run.mkdir()
    (run / "config.yaml").write_text("name: x\n")
    assert main(["evaluate", str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "checkpoint" in err


def test_evaluate_refuses_to_change_the_trained_config(runs, capsys):
    assert main(["evaluate", str(runs / "doe_net"), "--set", "net.widths=[8,16]"]) == 2
    assert "evaluation" in capsys.readouterr().err


def test_evaluate_may_set_the_classic_elements_a_run_does_not_read():
    """A learned DOE's run never reads ``doe.cubic_waves``: ``--set`` chooses the plate of ``cubic+wiener``;
    a cubic run was trained with its plate, which stays."""
    from edofproj.errors import EdofprojError
    from edofproj.evaluation.pipeline import evaluation_config

    learned = load_config("cpu")
    assert evaluation_config(learned, ["doe.cubic_waves=7", "doe.axicon_far_mm=600"]).doe.cubic_waves == 7.0
    cubic = load_config("cpu", ["doe.kind=cubic"])
    assert evaluation_config(cubic, ["doe.axicon_near_mm=400"]).doe.axicon_near_mm == 400.0
    for key in ("doe.cubic_waves=7", "doe.kind=axicon", "doe.levels=8"):
        with pytest.raises(EdofprojError, match="doe.kind=cubic run does not read"):
            evaluation_config(cubic, [key])


def test_compensate_size_mismatch_names_both_sizes(runs, tmp_path, capsys):
    write_image(tmp_path / "target.png", torch.rand(3, 40, 50))
    write_image(tmp_path / "capture.png", torch.rand(3, 38, 50))
    code = main(
        [
            "compensate",
            str(runs / "doe_net"),
            "--image",
            str(tmp_path / "target.png"),
            "--capture",
            str(tmp_path / "capture.png"),
            "--out",
            str(tmp_path / "out.png"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "40x50" in err and "38x50" in err
    assert not (tmp_path / "out.png").exists()


def test_compensate_any_size_with_simulated_capture(runs, tmp_path, capsys):
    target = torch.rand(3, 37, 53)
    write_image(tmp_path / "target.png", target, bits=16)
    assert (
        main(
            [
                "compensate",
                str(runs / "doe_net"),
                "--image",
                str(tmp_path / "target.png"),
                "--depth-mm",
                "350",
                "--out",
                str(tmp_path / "proj.png"),
                "--preview",
                str(tmp_path / "shown.png"),
                "--bits",
                "16",
            ]
        )
        == 0
    )
    projector_input = read_image(tmp_path / "proj.png")
    assert projector_input.shape == (3, 37, 53)
    shown = read_image(tmp_path / "shown.png")
    assert shown.shape == (3, 37, 53)
    # the printed figures of the preview, checked with scikit-image on the files (issue 29)
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("against the target at 350 mm")][0]
    figures = [float(v) for v in re.findall(r"SSIM ([0-9.]+), PSNR ([0-9.]+) dB", line)[0]]
    truth, preview = read_image(tmp_path / "target.png").numpy(), shown.numpy()
    expected_psnr = peak_signal_noise_ratio(truth, preview, data_range=1.0)
    expected_ssim = structural_similarity(
        truth, preview, channel_axis=0, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
    )
    assert figures == pytest.approx([expected_ssim, expected_psnr], abs=6e-3)  # printed to 4 and 2 decimals
    assert "uncompensated projection SSIM" in line


def test_compensate_with_a_capture_file(runs, tmp_path):
    write_image(tmp_path / "target.png", torch.rand(3, 24, 30))
    write_image(tmp_path / "capture.png", torch.rand(3, 24, 30))
    assert (
        main(
            [
                "compensate",
                str(runs / "doe_net"),
                "--image",
                str(tmp_path / "target.png"),
                "--capture",
                str(tmp_path / "capture.png"),
                "--out",
                str(tmp_path / "proj.png"),
                "--bits",
                "16",
            ]
        )
        == 0
    )
    assert read_image(tmp_path / "proj.png").shape == (3, 24, 30)


def test_score_range_defaults_to_the_training_range_and_is_validated():
    from edofproj.config import ConfigError
    from edofproj.methods.compensators import score_range_mm

    assert score_range_mm(load_config(None, ["psf.depth_min_mm=275"])) == (275.0, 800.0)
    assert score_range_mm(load_config(None, ["psf.depth_min_mm=275", "evaluation.score_range_mm=[300,800]"])) == (
        300.0,
        800.0,
    )
    with pytest.raises(ConfigError, match="score_range_mm"):
        load_config(None, ["evaluation.score_range_mm=[800,300]"])
    with pytest.raises(ConfigError, match="wiener_tuning_metric"):
        load_config(None, ["evaluation.wiener_tuning_metric=mse"])


def test_a_baseline_that_differs_only_in_a_statement_fits_one_that_differs_in_physics_does_not(tmp_path):
    """The stated accuracy of the spectral sampling (a statement) does not make another projector;
    its sampling does (the shipped baselines were trained before the cpu preset restated it)."""
    import dataclasses

    from edofproj.methods.builder import baseline_mismatch
    from edofproj.methods.catalogue import method_spec

    cfg = load_config("cpu")
    spec = method_spec("cubic+net")
    baseline = load_config("cpu", ["doe.kind=cubic"])
    restated = dataclasses.replace(baseline, spectrum=dataclasses.replace(baseline.spectrum, stated_l1_error=0.5))
    assert baseline_mismatch(spec, tmp_path, cfg, restated) is None
    resampled = dataclasses.replace(baseline, spectrum=dataclasses.replace(baseline.spectrum, nodes_per_primary=3))
    assert "spectrum section differs" in baseline_mismatch(spec, tmp_path, cfg, resampled)


def test_depths_outside_the_score_range_are_stated_never_a_table_of_na(runs, tmp_path, capsys):
    """--depths-mm beyond the score range (here the training range, 300-800 mm): the headings say the depths
    scored, the notes say which lie outside the score and the trained range; one depth: its own."""
    for depths, span in (("1500,3000", "1500-3000"), ("500", "500")):
        out = tmp_path / depths.replace(",", "_")
        capsys.readouterr()
        argv = ["evaluate", str(runs / "doe_net"), "--methods", "doe", "--depths-mm", depths, "--out", str(out)]
        assert main(argv + ["--quiet"]) == 0
        printed, err = capsys.readouterr()
        summary = (out / "summary.md").read_text()
        assert f"over {span} mm" in summary and "over 300-800 mm" not in summary and "| NA" not in summary
        assert " NA " not in printed
        if depths == "500":
            assert "outside" not in err
        else:
            assert "depths 1500, 3000 mm lie outside the score range 300-800 mm" in err
            assert "depths 1500, 3000 mm lie outside the range the run was trained on, 300-800 mm" in err
            assert "outside the score range" in summary


def test_the_report_draws_each_design_with_its_best_blind_and_non_blind_method(evaluated):
    assert (evaluated / "figures" / "eval_designs_vs_depth.png").stat().st_size > 1000
    cfg = load_config(None, TINY)
    lo, hi = cfg.psf.depth_min_mm, cfg.psf.depth_max_mm  # the score range: the training range here
    _, rows = read_rows(evaluated / "metrics.csv")

    def mean_ssim(method):
        depths = sorted({float(r["depth_mm"]) for r in rows if lo <= float(r["depth_mm"]) <= hi})
        per_depth = [
            np.mean([float(r["ssim"]) for r in rows if r["method"] == method and float(r["depth_mm"]) == z])
            for z in depths
        ]
        return float(np.mean(per_depth))

    report = " ".join((evaluated / "report.md").read_text().split())
    assert "Each optical design at its best" in report and "](figures/eval_designs_vs_depth.png)" in report
    for design, kind, candidates in (
        ("bare lens", "blind", ("lens", "lens+net")),
        ("bare lens", "non-blind", ("lens+wiener", "lens+cls")),
        ("learned DOE", "blind", ("doe", "doe+ensemble", "doe+net")),
        ("learned DOE", "non-blind", ("doe+wiener",)),
    ):
        best = max(candidates, key=mean_ssim)
        assert f"`{best}` ({kind}, {mean_ssim(best):.3f})" in report, (design, kind, best)


def test_an_evaluation_simulates_each_design_at_the_depths_its_cost_is_counted_for(runs, tmp_path):
    """:func:`design_depths_m` (what the demo's time predictor counts for the cubic plate) is the set of
    depths at which the evaluation simulates a design, compensation by compensation."""
    from edofproj.evaluation.pipeline import design_depths_m, evaluate_run

    ev = evaluate_run(runs / "doe_net", out_dir=tmp_path, methods=["lens", "lens+wiener", "doe", "doe+ensemble"])
    for key, compensations in (("lens", {"none", "wiener"}), ("run", {"none", "ensemble"})):
        simulated = sorted(ev.designs[key]._cache)
        counted = [int(k) for k in np.round(design_depths_m(ev.cfg, compensations) * 1e6)]
        assert simulated == counted, key
