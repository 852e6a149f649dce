"""Training on a folder of images: the count and split are printed, and the run's config.yaml
stores the folder absolute, so the run resumes and loads from any working directory (issue 29)."""

from __future__ import annotations

import numpy as np
import torch

from edofproj.cli import main
from edofproj.config import dump_config, load_config
from edofproj.data import folder_split
from edofproj.imaging.image_io import write_image
from edofproj.runs import load_run


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
