"""Training on a folder of images: the count and split are printed, and the run's config.yaml
stores the folder absolute, so the run resumes and loads from any working directory (issue 29)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.config import dump_config, load_config
from edofproj.data import folder_split
from edofproj.imaging.image_io import write_image
from edofproj.runs import check_resume_config, load_run, with_absolute_paths, write_run_config


def test_config_yaml_stores_paths_absolute_and_resume_accepts_a_relative_run(tmp_path, monkeypatch):
    """Without training: the run's config.yaml holds data.folder (and every path key) absolute; a config
    saved relative (before this rule) still resumes from its own directory; builtin:NAME stays a name."""
    from edofproj.config import Config

    monkeypatch.chdir(tmp_path)
    cfg = Config()
    cfg.data.source, cfg.data.folder, cfg.data.test_folder = "folder", "photos", "../held"
    cfg.doe.kind, cfg.doe.path = "file", "builtin:cpu-doe-net"
    (tmp_path / "run").mkdir()
    write_run_config(tmp_path / "run", cfg)
    saved = load_config(str(tmp_path / "run" / "config.yaml"))
    assert saved.data.folder == str(tmp_path / "photos") and saved.data.test_folder == str(tmp_path.parent / "held")
    assert saved.doe.path == "builtin:cpu-doe-net" and cfg.data.folder == "photos"  # the caller's config untouched
    check_resume_config(tmp_path / "run", cfg)  # the same folders, given relative: resumable
    (tmp_path / "run" / "config.yaml").write_text(dump_config(cfg))  # a run saved with relative paths
    check_resume_config(tmp_path / "run", with_absolute_paths(cfg))


@pytest.mark.slow  # trains (one step)
def test_train_on_a_relative_folder_prints_the_split_and_stores_it_absolute(tmp_path, monkeypatch, tiny_config, capsys):
    work, elsewhere = tmp_path / "work", tmp_path / "elsewhere"
    (work / "photos").mkdir(parents=True)
    elsewhere.mkdir()
    rng = np.random.default_rng(0)
    for i in range(5):
        write_image(work / "photos" / f"p{i}.png", torch.from_numpy(rng.random((3, 40, 48))).float())
    write_image(work / "photos" / "mini.png", torch.rand(3, 8, 8))  # smaller than the 32-px crop
    cfg = tiny_config("data.source=folder", "data.folder=photos", "train.batch_size=1", "train.steps=1")
    (work / "tiny.yaml").write_text(dump_config(cfg))
    monkeypatch.chdir(work)

    assert main(["train", "--config", "tiny.yaml", "--out", "run", "--quiet"]) == 0
    out = capsys.readouterr().out
    train, test = folder_split(work / "photos", cfg.data.test_fraction)
    assert f"data: 6 images in 'photos': {len(train)} for training, {len(test)} held out for testing" in out
    assert "mini.png" in {p.name for p in train}  # the split of these names: mini.png trains
    assert "1 training image(s) skipped (unreadable or smaller than the 32 px crop)" in out
    saved = load_config(str(work / "run" / "config.yaml"))
    assert saved.data.folder == str(work / "photos")  # absolute, whatever the working directory was

    monkeypatch.chdir(elsewhere)  # resume and load from another directory
    assert main(["train", "--out", str(work / "run"), "--resume", "--steps", "2", "--quiet"]) == 0
    assert "steps 1 -> 2 of 2" in capsys.readouterr().out
    assert load_run(work / "run").step == 2
