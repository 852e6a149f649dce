"""Fault tier: a trained run meets locked outputs, skipped images, a mismatched network, bad measured PSFs."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.config import load_config
from edofproj.locking import directory_lock
from edofproj.optics.psf_bank import PSFBank
from tiny_configs import TINY_EVALUATION

pytestmark = pytest.mark.slow  # trains a run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from edofproj.training.trainer import train

    out = tmp_path_factory.mktemp("faults") / "run"
    train(load_config(None, TINY_EVALUATION), out, progress=False)
    return out


def _psf_file(path, psf):
    PSFBank(psf=torch.from_numpy(psf), depths_m=np.array([0.4, 0.6]), pixel_pitch_m=np.full(2, 1e-3)).save(path)
    return path


def test_evaluate_names_the_skipped_image_in_its_report(run, tmp_path, capsys):
    import cv2

    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for name in ("c.png", "d.png"):  # sorted after broken.png (data.max_test_images=2 stops at two)
        cv2.imwrite(str(images / name), (rng.random((48, 64, 3)) * 255).astype(np.uint8))
    (images / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(50))
    out = tmp_path / "ev"
    args = ["evaluate", str(run), "--images", str(images), "--out", str(out), "--methods", "doe", "--quiet"]
    assert main(args) == 0
    for document in ("summary.md", "report.md"):
        text = (out / document).read_text()
        assert "broken.png" in text and "2 image(s) scored; 1 skipped as unreadable" in text
    assert "broken.png" in capsys.readouterr().err


def test_evaluate_does_not_score_images_smaller_than_the_evaluation_size(run, tmp_path, capsys):
    """A 30x30 image enlarged to 48x64 would be smooth and score well: it is skipped and counted (issue 29)."""
    import cv2

    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    cv2.imwrite(str(images / "a_small.png"), (rng.random((30, 30, 3)) * 255).astype(np.uint8))
    cv2.imwrite(str(images / "b_large.png"), (rng.random((48, 64, 3)) * 255).astype(np.uint8))
    out = tmp_path / "ev"
    args = ["evaluate", str(run), "--images", str(images), "--out", str(out), "--methods", "doe", "--quiet"]
    assert main(args) == 0
    assert "30x30 px is smaller than the evaluation size 48x64" in capsys.readouterr().err
    assert "1 image(s) scored; 1 skipped as smaller than the evaluation size" in (out / "report.md").read_text()
    scored = {line.split(",")[2] for line in (out / "metrics.csv").read_text().splitlines()[1:]}
    assert scored == {"b_large.png"}


def test_evaluate_refuses_an_output_another_process_writes(run, tmp_path, capsys):
    out = tmp_path / "ev"
    with directory_lock(out, "edofproj evaluate"):
        code = main(["evaluate", str(run), "--out", str(out), "--methods", "doe", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "--out" in err and "is being written by edofproj evaluate" in err
    assert not out.exists() or not any(out.iterdir())


def test_a_network_not_matching_its_checkpoint_names_the_difference(run, tmp_path, capsys):
    changed = tmp_path / "changed"
    shutil.copytree(run, changed)
    config = (changed / "config.yaml").read_text()
    assert "  - 4\n  - 8\n" in config
    (changed / "config.yaml").write_text(config.replace("  - 4\n  - 8\n", "  - 6\n  - 8\n", 1))
    assert main(["evaluate", str(changed), "--methods", "doe+net", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "of different shape" in err and "in the checkpoint but" in err and "net.* settings" in err


def test_finetune_refuses_an_all_zero_measured_psf_and_writes_nothing(run, tmp_path, capsys):
    zero = _psf_file(tmp_path / "zero.npz", np.zeros((2, 3, 15, 15), np.float32))
    out = tmp_path / "ft"
    assert main(["finetune", str(run), "--psfs", str(zero), "--steps", "1", "--out", str(out)]) == 2
    assert "holds no light" in capsys.readouterr().err and not out.exists()


def test_finetune_into_a_used_directory_does_not_suggest_resume(run, tmp_path, capsys):
    out = tmp_path / "used"
    out.mkdir()
    (out / "x.txt").write_text("x")
    psf = np.zeros((2, 3, 15, 15), np.float32)
    psf[:, :, 7, 7] = 0.9
    good = _psf_file(tmp_path / "good.npz", psf)
    assert main(["finetune", str(run), "--psfs", str(good), "--steps", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "choose another --out" in err and "--resume" not in err


def test_an_interrupted_evaluate_leaves_the_previous_set_alone(run, tmp_path, capsys, monkeypatch):
    """Killed after its tables but before its reports: the folder keeps the previous evaluation's
    files, unchanged, and no new table beside them."""
    import edofproj.reporting.writeup as writeup

    out = tmp_path / "ev"
    args = ["evaluate", str(run), "--out", str(out), "--methods", "doe", "--quiet"]
    assert main(args) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(writeup, "write_documents", interrupted)
    assert main(args + ["--depths-mm", "400,600"]) == 130
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


def test_re_evaluating_into_the_same_out_leaves_no_file_of_the_previous_run(run, tmp_path, capsys):
    """A surface evaluation, then a flat one, then a scene one into the same --out: each replaces the
    previous set as a whole (no surface_metrics.csv beside the new report); the user's file stays."""
    out = tmp_path / "ev"
    base = ["evaluate", str(run), "--out", str(out), "--methods", "doe", "--quiet"]
    assert main(base + ["--surface", "white", "--depths-mm", "400"]) == 0
    assert {"surface_metrics.csv", "surface_summary.md"} <= {p.name for p in out.iterdir()}
    (out / "notes.txt").write_text("the user's\n")
    assert main(base + ["--depths-mm", "400"]) == 0
    names = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert {"metrics.csv", "report.md", "notes.txt"} <= names
    assert not names & {"surface_metrics.csv", "surface_summary.md", "figures/eval_surfaces.png"}
    assert main(base + ["--scene", "steps"]) == 0
    names = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert {"scene_metrics.csv", "scene_summary.md", "notes.txt"} <= names
    assert not names & {"metrics.csv", "report.md", "report.html", "summary.md", "tilted_metrics.csv"}
    assert not [p for p in out.iterdir() if p.name.startswith(".evaluate-staging-")]
