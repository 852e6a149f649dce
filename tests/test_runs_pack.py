"""A run packed into files of bounded size and unpacked: byte-identical files, refusals with nothing written."""

from __future__ import annotations

import hashlib
import io
import json
import tarfile

import numpy as np
import pytest
import torch

from edofproj.builtin_runs import KEPT_CHECKPOINT_KEYS
from edofproj.config import Config, dump_config
from edofproj.errors import EdofprojError
from edofproj.runs.checkpoint import load_checkpoint, save_checkpoint
from edofproj.runs.pack import pack_run, read_manifest, tar_bytes, unpack_run


def fake_run(folder, parameters: int = 20_000):
    """A run directory as training leaves it: config, DOE, log, figures, checkpoints (random float32 state)."""
    generator = torch.Generator().manual_seed(1)
    net = {"w": torch.randn(parameters, generator=generator), "b": torch.randn(7, generator=generator)}
    moments = {0: {"step": torch.tensor(5.0), "exp_avg": torch.randn(parameters, generator=generator)}}
    folder.mkdir(parents=True)
    (folder / "config.yaml").write_text(dump_config(Config()))
    np.savez(folder / "doe.npz", height_m=np.linspace(0, 1e-6, 33))
    (folder / "train_log.csv").write_text("step,loss,mse,perceptual,lr,seconds\n1,0.5,0.4,,0.001,0.1\n")
    (folder / "figures").mkdir()
    (folder / "figures" / "loss.png").write_bytes(b"\x89PNG not really" * 40)
    state = {"step": 5, "elapsed_seconds": 0.5, "doe": {}, "net": net, "config": {}}
    state.update(optimizer={"state": moments, "param_groups": []}, scheduler={"last_epoch": 5}, rng={})
    for step in (4, 5):
        save_checkpoint(folder / "checkpoints", dict(state, step=step), keep=2)
    return folder


def run_files(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_round_trip_gives_the_run_files_byte_for_byte_in_parts_of_bounded_size(tmp_path):
    run = fake_run(tmp_path / "run")
    part_bytes = 40_960
    packed = pack_run(run, tmp_path / "out", "run", part_bytes=part_bytes, max_parts=20)
    sizes = [p.stat().st_size for p in packed.parts]
    assert all(size <= part_bytes for size in sizes) and sizes[:-1] == [part_bytes] * (len(sizes) - 1)
    packed_files = ["config.yaml", "doe.npz", "train_log.csv", "figures/loss.png", "checkpoints/last.pt"]
    assert sum(sizes) == packed.tar_bytes == tar_bytes([(run / f).stat().st_size for f in packed_files])
    manifest = read_manifest(packed.manifest)
    assert (manifest["step"], manifest["resumable"]) == (5, True)
    assert sorted(manifest["files"]) == sorted(packed_files)  # the older step file is not packed

    unpack_run(packed.manifest, tmp_path / "back")
    original, back = run_files(run), run_files(tmp_path / "back")
    assert sorted(back) == sorted(packed_files)
    assert all(back[name] == original[name] for name in back)


def test_a_run_over_the_parts_allowed_is_refused_with_nothing_written(tmp_path):
    run = fake_run(tmp_path / "run")
    size = tar_bytes([p.stat().st_size for p in run.rglob("*") if p.is_file() and "step_" not in p.name])
    with pytest.raises(EdofprojError, match="more than the 2 allowed"):
        pack_run(run, tmp_path / "out", part_bytes=size // 3 + 1, max_parts=2)
    assert not (tmp_path / "out").exists()


def test_slim_pack_keeps_the_network_not_the_optimizer(tmp_path):
    run = fake_run(tmp_path / "run")
    full = pack_run(run, tmp_path / "full", resumable=True)
    slim = pack_run(run, tmp_path / "slim", resumable=False)
    assert read_manifest(slim.manifest)["resumable"] is False
    assert slim.tar_bytes < full.tar_bytes
    unpack_run(slim.manifest, tmp_path / "back")
    state = load_checkpoint(tmp_path / "back" / "checkpoints" / "last.pt")
    assert set(state) <= set(KEPT_CHECKPOINT_KEYS) and "optimizer" not in state
    assert torch.equal(state["net"]["w"], load_checkpoint(run / "checkpoints" / "last.pt")["net"]["w"])


def test_a_new_pack_removes_the_parts_an_earlier_larger_pack_left(tmp_path):
    run = fake_run(tmp_path / "run")
    first = pack_run(run, tmp_path / "out", part_bytes=20_480, max_parts=50)
    second = pack_run(run, tmp_path / "out", part_bytes=81_920, max_parts=50)
    assert len(second.parts) < len(first.parts)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        [second.manifest.name] + [p.name for p in second.parts]
    )


@pytest.mark.parametrize("damage", ["flip", "missing", "truncate"])
def test_a_damaged_or_missing_part_is_refused_and_no_run_is_written(tmp_path, damage):
    run = fake_run(tmp_path / "run")
    packed = pack_run(run, tmp_path / "out", part_bytes=20_480, max_parts=50)
    part = packed.parts[1]
    if damage == "flip":
        data = bytearray(part.read_bytes())
        data[100] ^= 1
        part.write_bytes(bytes(data))
    elif damage == "missing":
        part.unlink()
    else:
        part.write_bytes(part.read_bytes()[:-1])
    with pytest.raises(EdofprojError, match=part.name) as error:
        unpack_run(packed.manifest, tmp_path / "back")
    assert "\n" not in str(error.value)
    assert not (tmp_path / "back").exists()
    assert not [p for p in tmp_path.iterdir() if ".unpacking-" in p.name]


def test_a_member_the_manifest_does_not_list_is_refused_before_it_is_written(tmp_path):
    """A forged pack: its part matches the manifest, but the tar holds a path that climbs out."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        info = tarfile.TarInfo("../escaped.txt")
        info.size = 3
        tar.addfile(info, io.BytesIO(b"bad"))
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.tar.000").write_bytes(buffer.getvalue())

    manifest = {
        "format": "edofproj-run-pack-v1",
        "name": "run",
        "step": 1,
        "resumable": True,
        "tar_bytes": len(buffer.getvalue()),
        "files": {"config.yaml": {"bytes": 3, "sha256": hashlib.sha256(b"bad").hexdigest()}},
        "parts": [
            {
                "file": "run.tar.000",
                "bytes": len(buffer.getvalue()),
                "sha256": hashlib.sha256(buffer.getvalue()).hexdigest(),
            }
        ],
    }
    (out / "run.pack.json").write_text(json.dumps(manifest))
    with pytest.raises(EdofprojError, match="does not list"):
        unpack_run(out / "run.pack.json", tmp_path / "back" / "run")
    assert not (tmp_path / "back" / "escaped.txt").exists() and not (tmp_path / "back" / "run").exists()


def test_refusals_name_the_problem_in_one_line(tmp_path):
    run = fake_run(tmp_path / "run")
    packed = pack_run(run, tmp_path / "out")
    with pytest.raises(EdofprojError, match="not empty"):
        unpack_run(packed.manifest, run)  # an existing run is never overwritten
    with pytest.raises(EdofprojError, match="no pack manifest"):
        unpack_run(tmp_path / "out" / "other.pack.json", tmp_path / "back")
    (tmp_path / "bad.pack.json").write_text('{"format": "something else"}')
    with pytest.raises(EdofprojError, match="not an edofproj run pack manifest"):
        unpack_run(tmp_path / "bad.pack.json", tmp_path / "back")
    with pytest.raises(EdofprojError, match="not a trained run"):
        pack_run(tmp_path / "out", tmp_path / "out2")
    with pytest.raises(EdofprojError, match="contains the input"):
        pack_run(run, tmp_path)  # the pack's folder may not hold the run's files
