"""Fine-tuning on a PSF map (``finetune --psf-map``) and the fine-tuned network compensating the
map's blur (``compensate --psf-map --method net``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edofproj.cli import main
from edofproj.imaging.image_io import read_image, write_image
from edofproj.procams.measured_blur import measured_blur
from edofproj.procams.psf_map import PSFMap, covariance, save_psf_maps
from edofproj.runs import load_run
from edofproj.runs.checkpoint import load_newest_intact_checkpoint
from edofproj.training.finetune import MAP_NODE_SPACING_PX, MeasuredPSFTable

H, W = 64, 96


def colour_map(sigma: float, channel: str) -> PSFMap:
    xs, ys = np.arange(0.0, W, 16.0), np.arange(0.0, H, 16.0)
    cov = np.array([[covariance(sigma * (1 + x / W), sigma, 0.0) for x in xs] for _ in ys])
    return PSFMap(xs=xs, ys=ys, cov=cov, offset_px=np.zeros(2), fitted=np.ones(cov.shape[:2], bool),
                  projector_hw=(H, W), channel=channel)  # fmt: skip


@pytest.fixture
def map_file(tmp_path):
    path = tmp_path / "map.npz"
    save_psf_maps(path, [colour_map(0.8, "red"), colour_map(1.2, "green"), colour_map(1.6, "blue")])
    return path


def test_the_table_draws_the_maps_node_kernels_per_colour(map_file):
    table = MeasuredPSFTable.from_psf_map(map_file, 0.5, seed=0)
    op = measured_blur({c.channel: c for c in (colour_map(0.8, "red"), colour_map(1.2, "green"), colour_map(1.6, "blue"))},
                       node_spacing_px=MAP_NODE_SPACING_PX, rank_tolerance=0.0)  # fmt: skip
    nodes = op.kernels.reshape(-1, *op.kernels.shape[2:]).float()  # (P, 3, K, K)
    assert tuple(table.psf.shape) == (1, *nodes.shape)
    torch.testing.assert_close(table.psf[0], nodes)
    drawn = table(np.full(16, 0.5))
    for psf in drawn:  # each sample is one node's kernels, red narrower than blue
        assert min(float((psf - n).abs().max()) for n in nodes) == 0.0
        assert float(psf[0].max()) > float(psf[2].max())


def test_finetune_on_a_map_then_compensate_with_the_network(map_file, tmp_path, capsys):
    out = tmp_path / "tuned"
    code = main(["finetune", "builtin:cpu-doe-net", "--psf-map", str(map_file), "--steps", "2", "--batch-size", "2",
                 "--out", str(out)])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "node kernels of the PSF map" in printed.out
    checkpoint, _ = load_newest_intact_checkpoint(out / "checkpoints")
    assert checkpoint["psf_map"] == str(map_file)
    before, after = load_run("builtin:cpu-doe-net").net.state_dict(), load_run(out).net.state_dict()
    assert any(not torch.equal(before[k], after[k]) for k in before if before[k].is_floating_point())

    target = torch.rand(3, H, W, generator=torch.Generator().manual_seed(0))
    write_image(tmp_path / "target.png", target, bits=8)
    proj = tmp_path / "proj.png"
    code = main(["compensate", "--psf-map", str(map_file), "--image", str(tmp_path / "target.png"), "--method", "net",
                 "--run", str(out), "--bits", "16", "--out", str(proj)])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "method net" in printed.out and "per colour" in printed.out
    assert tuple(read_image(proj).shape) == (3, H, W)
    # the same network, run by hand on the map's simulated projection, gives the file's image
    from edofproj.procams.psf_map import load_psf_maps

    op = measured_blur(load_psf_maps(map_file))
    shown = read_image(tmp_path / "target.png")[None]
    with torch.no_grad():
        expected = load_run(out).net(shown, op(shown)).clamp(0, 1)[0]
    assert float((read_image(proj) - expected).abs().max()) <= 1.0 / 65535 + 1e-6


def test_finetune_refuses_two_sources(map_file, tmp_path, capsys):
    code = main(["finetune", "builtin:cpu-doe-net", "--psf-map", str(map_file), "--psfs", str(map_file),
                 "--out", str(tmp_path / "o")])  # fmt: skip
    err = capsys.readouterr().err
    assert code != 0 and "one of them" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
