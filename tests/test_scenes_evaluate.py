"""``evaluate RUN --scene``: scores over the objects' pixels, files, and a run trained on varying screens."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
import torch

from edofproj.evaluation.scenes import masked_scores
from edofproj.training.sampling import BatchShard, sample_depth_maps


def test_masked_scores_count_only_the_object():
    """A display equal to the masked target plus delta on the object: PSNR = -10 log10(delta^2); a perfect
    display scores SSIM 1 whatever the target holds off the object."""
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(1, 3, 40, 48, generator=generator)
    hit = torch.zeros(40, 48, dtype=torch.bool)
    hit[5:35, 8:30] = True
    delta = 0.05
    shifted = (target + delta) * hit
    scores, _ = masked_scores(shifted, target, hit)
    assert scores[0]["psnr"] == pytest.approx(-10 * math.log10(delta**2), abs=1e-3)
    perfect, local = masked_scores(target * hit, target, hit)
    assert perfect[0]["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert torch.isnan(local[0][~hit]).all()


def test_varying_screens_are_the_same_under_data_parallelism():
    whole = sample_depth_maps(3, 7, BatchShard.for_rank(4, 0, 1), 16, 0.3, 0.8)
    halves = [sample_depth_maps(3, 7, BatchShard.for_rank(4, r, 2), 16, 0.3, 0.8) for r in range(2)]
    np.testing.assert_array_equal(whole, np.concatenate(halves))
    assert whole.shape == (4, 16, 16) and whole.min() >= 0.3 and whole.max() <= 0.8


SCENE_RUN = ["optics.width_px=64", "optics.height_px=48", "psf.depth_min_mm=300", "psf.depth_max_mm=800"]


@pytest.mark.slow
def test_evaluate_scenes_on_runs_trained_on_flat_and_varying_screens(tmp_path, capsys):
    from edofproj.cli import main
    from edofproj.config import load_config
    from edofproj.training.trainer import train
    from tiny_configs import TINY_EVALUATION

    for screens in ("flat", "varying"):
        run = tmp_path / screens
        train(load_config(None, TINY_EVALUATION + SCENE_RUN + [f"train.screens={screens}"]), run, progress=False)
        out = tmp_path / f"eval_{screens}"
        code = main(
            ["evaluate", str(run), "--scene", "sphere_wall,steps", "--methods", "lens,doe,doe+wiener,doe+net"]
            + ["--out", str(out), "--quiet"]
        )
        assert code == 0
        with open(out / "scene_metrics.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        assert {r["scene"] for r in rows} == {"sphere_wall", "steps"}
        assert {r["method"] for r in rows} == {"lens", "doe", "doe+wiener", "doe+net"}
        assert all(0 < float(r["ssim"]) <= 1 for r in rows)
        for name in ("eval_scenes.png", "eval_scene_ssim.png"):
            assert (out / "figures" / name).stat().st_size > 1000
        assert "sphere_wall (340-750 mm)" in (out / "scene_summary.md").read_text()

    # a scene beyond the run's PSF range: one line, exit 2, nothing written
    far = tmp_path / "far.yaml"
    far.write_text("background_m: 0.95\n")
    out = tmp_path / "eval_far"
    assert main(["evaluate", str(tmp_path / "flat"), "--scene", str(far), "--out", str(out), "--quiet"]) == 2
    assert "cover 300.0-800.0 mm" in capsys.readouterr().err
    assert not out.exists()
