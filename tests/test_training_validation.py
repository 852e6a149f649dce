"""Training with the safe network: the linear base filter follows the DOE, validation is logged,
and a resumed run matches an uninterrupted one."""

from __future__ import annotations

import torch

from edofproj.doe import build_run_doe
from edofproj.runs.checkpoint import load_newest_intact_checkpoint
from edofproj.training.linear_filter import current_linear_filter
from edofproj.training.trainer import build_psf_source, train
from edofproj.training.validation import COLUMNS, VALIDATION_LOG, read_validation_log

SAFE = (
    "net.linear_base=ensemble",
    "net.linear_radius=11",
    "train.steps=4",
    "train.batch_size=2",
    "train.checkpoint_every=2",
    "train.linear_every=2",
    "train.validate_every=2",
    "train.validation_images=2",
    "data.colour_augment=0.5",
)


def test_safe_run_keeps_the_final_does_filter_and_logs_validation(tiny_config, tmp_path):
    cfg = tiny_config(*SAFE)
    train(cfg, tmp_path / "run", progress=False)
    rows = read_validation_log(tmp_path / "run" / VALIDATION_LOG)
    assert [r["step"] for r in rows] == [2.0, 4.0]
    assert set(rows[0]) == set(COLUMNS)
    assert all(0 < r["ssim_linear"] <= 1 and r["de2000_net"] >= 0 for r in rows)

    # the checkpoint's filter is the depth-ensemble filter of the DOE it holds (recomputed here)
    checkpoint, _ = load_newest_intact_checkpoint(tmp_path / "run" / "checkpoints")
    doe = build_run_doe(cfg)
    doe.load_state_dict(checkpoint["doe"])
    expected = current_linear_filter(cfg, build_psf_source(cfg, doe, True, torch.device("cpu")))
    torch.testing.assert_close(checkpoint["net"]["linear_base.kernel"], expected.kernel, atol=1e-6, rtol=0)
    identity = torch.zeros_like(expected.kernel)
    identity[:, 11, 11] = 1
    assert not torch.allclose(expected.kernel, identity)


def test_resumed_safe_run_matches_the_uninterrupted_one(tiny_config, tmp_path):
    cfg = tiny_config(*SAFE)
    train(cfg, tmp_path / "straight", progress=False)
    train(cfg, tmp_path / "chunked", stop_after=2, progress=False)
    train(cfg, tmp_path / "chunked", resume=True, progress=False)
    a, _ = load_newest_intact_checkpoint(tmp_path / "straight" / "checkpoints")
    b, _ = load_newest_intact_checkpoint(tmp_path / "chunked" / "checkpoints")
    for key, value in a["net"].items():
        assert torch.equal(value, b["net"][key]), key
    assert read_validation_log(tmp_path / "straight" / VALIDATION_LOG) == read_validation_log(
        tmp_path / "chunked" / VALIDATION_LOG
    )
