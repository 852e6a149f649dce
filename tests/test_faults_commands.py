"""Fault tier: what a hostile tester gave the commands (issue: sizes, arguments, tables, designs,
interrupted writes, camera processes), each refused in one line before anything is allocated or
written, or cleaned up by the next command."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from edofproj.builtin_runs import ROOT as BUILTIN_ROOT
from edofproj.cli import main
from edofproj.config import load_config
from edofproj.doe import load_doe, save_doe
from edofproj.doe.storage import TabulatedRadialDOE
from edofproj.errors import ConfigError, EdofprojError, RecoveryWarning
from edofproj.evaluation.results import MetricsTable
from edofproj.limits import MemoryLimitError
from edofproj.optics.materials import height_2pi_m
from edofproj.optics.psf_bank import PSFBank
from tiny_configs import TINY_TRAINING

MEMORY = str(16 << 30)  # the tests' machine: 16 GiB available to edofproj


@pytest.fixture(autouse=True)
def sixteen_gib(monkeypatch):
    monkeypatch.setenv("EDOFPROJ_MEMORY_BYTES", MEMORY)


def run_error(capsys, argv) -> str:
    """Run the CLI expecting a user error: exit code 2 and exactly one line on stderr."""
    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    lines = [line for line in lines if not line.startswith("edofproj: warning:")]
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: "), lines
    return lines[0]


def _psf_file(path, depths=(0.4, 0.6), window=11):
    c = np.arange(window) - window // 2
    spot = np.exp(-(c[:, None] ** 2 + c[None, :] ** 2) / 4.5)
    psf = np.broadcast_to(0.9 * spot / spot.sum(), (len(depths), 3, window, window)).astype(np.float32)
    PSFBank(psf=torch.from_numpy(psf.copy()), depths_m=np.array(depths), pixel_pitch_m=np.full(len(depths), 1e-3)).save(
        path
    )
    return path


# ----------------------------------------------------------------------------- sizes (item 11)


def test_a_huge_training_batch_is_refused_when_the_config_is_read(tmp_path, capsys):
    with pytest.raises(MemoryLimitError, match="train.batch_size=100000000 crops of 128x128 px needs about"):
        load_config("cpu", ["train.batch_size=100000000"])
    out = tmp_path / "t"
    line = run_error(capsys, ["train", "--config", "cpu", "--set", "train.batch_size=100000000", "--out", str(out)])
    assert "use a smaller train.batch_size" in line and not out.exists()


def test_a_huge_evaluation_image_is_refused_when_the_config_is_read():
    with pytest.raises(MemoryLimitError, match="evaluation.image_size=\\[100000, 100000\\]"):
        load_config("cpu", ["evaluation.image_size=[100000,100000]"])


def test_a_range_of_too_many_depths_is_refused_before_it_is_made(tmp_path, capsys):
    line = run_error(
        capsys, ["evaluate", "builtin:cpu-doe-net", "--depths-mm", "300:800:0.00001", "--out", str(tmp_path / "e")]
    )
    assert "gives 50000000 values, more than 10000: use a larger step" in line
    assert not (tmp_path / "e").exists()


def test_export_and_bench_refuse_frames_that_cannot_fit(tmp_path, capsys):
    line = run_error(
        capsys,
        ["export", "builtin:cpu-doe-net", "--height", "100000", "--width", "100000", "--out", str(tmp_path / "n.onnx")],
    )
    assert "exporting at 100000x100000 px needs about" in line and not (tmp_path / "n.onnx").exists()
    line = run_error(capsys, ["bench", "--sizes", "64x64,100000x100000"])
    assert "a 100000x100000 frame needs about" in line and "use smaller --sizes" in line


# ----------------------------------------------------------------------------- finetune (items 11, 13, 14)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--lr", "nan"], "--lr nan must be a positive, finite learning rate"),
        (["--lr", "-1"], "--lr -1.0 must be a positive"),
        (["--batch-size", "0"], "--batch-size 0 must be >= 1"),
    ],
)
def test_finetune_arguments_are_checked_first(tmp_path, capsys, extra, message):
    out = tmp_path / "ft"
    line = run_error(
        capsys, ["finetune", "builtin:cpu-doe-net", "--psfs", str(tmp_path / "none.npz"), "--out", str(out), *extra]
    )
    assert message in line and not out.exists()


def test_finetune_refuses_a_batch_that_cannot_fit_before_training(tmp_path, capsys):
    out = tmp_path / "ft"
    psfs = _psf_file(tmp_path / "psf.npz")
    args = ["finetune", "builtin:cpu-doe-net", "--psfs", str(psfs), "--out", str(out), "--batch-size", "100000000"]
    line = run_error(capsys, args)
    assert "train.batch_size=100000000" in line and (not out.exists() or not any(out.iterdir()))


def test_finetune_refuses_a_truncated_per_patch_file_in_one_line(tmp_path, capsys):
    good = tmp_path / "good.npz"
    np.savez(good, psf=np.full((4, 3, 5, 5), 0.03), depths_m=np.array([0.5]))
    truncated = tmp_path / "patches.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    line = run_error(
        capsys, ["finetune", "builtin:cpu-doe-net", "--patch-psfs", str(truncated), "--out", str(tmp_path / "ft")]
    )
    assert "per-patch PSF file" in line and "truncated or damaged" in line


# ----------------------------------------------------------------------------- train (item 12)


def test_train_refuses_a_sampling_before_writing_anything(tmp_path, capsys):
    out = tmp_path / "run"
    overrides = [
        a for item in TINY_TRAINING + ["psf.pupil_samples=64", "data.source=dead-leaves"] for a in ("--set", item)
    ]
    line = run_error(capsys, ["train", *overrides, "--steps", "2", "--quiet", "--out", str(out)])
    assert "pupil_samples=64" in line
    assert not out.exists() or not any(out.iterdir())  # a fixed rerun is not told "use --resume"


# ----------------------------------------------------------------------------- smaller tracebacks (item 13)


def test_an_empty_depth_map_is_one_line(tmp_path, capsys):
    image = tmp_path / "i.png"
    import cv2

    cv2.imwrite(str(image), np.zeros((16, 16, 3), np.uint8))
    (tmp_path / "d.npy").write_bytes(b"")
    line = run_error(
        capsys,
        [
            "render",
            "--image",
            str(image),
            "--doe",
            "lens",
            "--depth-map",
            str(tmp_path / "d.npy"),
            "--out",
            str(tmp_path / "o.png"),
        ],
    )
    assert "depth map" in line and "d.npy" in line


def test_ctrl_c_while_the_commands_load_ends_cleanly(monkeypatch, capsys):
    import edofproj.cli as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["psf", "--help"]) == 130
    assert capsys.readouterr().err.strip() == "edofproj: interrupted"


# ----------------------------------------------------------------------------- summarize (items 13, 14)


def _table(depths=(300.0, 500.0), images=("a", "b"), value=0.8, method_values=None):
    table = MetricsTable(("method", "depth_mm", "image"), ("ssim",))
    for method, base in (method_values or {"doe+net": value, "doe": 0.5}).items():
        for depth in depths:
            for image in images:
                table.add(method=method, depth_mm=depth, image=image, ssim=base)
    return table


@pytest.mark.parametrize(
    "second, extra, message",
    [
        (lambda p: _table(depths=(300.0, 600.0)).write_csv(p), [], "other depths within 300-800 mm"),
        (lambda p: p.write_text(_table().to_csv()[:-12]), [], "truncated"),
        (lambda p: p.write_text("\n".join(_table().to_csv().splitlines()[:-2]) + "\n"), [], "lacks 2 of the 4 scores"),
        (lambda p: p.write_bytes(_table().to_csv().encode("utf-16")), [], "not UTF-8"),
        (lambda p: _table(value=float("nan")).write_csv(p), [], "no ssim score \\(NA\\) for doe\\+net"),
        (lambda p: _table(value=0.81).write_csv(p), ["--reference", "nosuch"], "--reference 'nosuch' is not a method"),
        (
            lambda p: _table(value=float("inf")).write_csv(p),
            [],
            "4 ssim score\\(s\\) of doe\\+net that no evaluation gives",
        ),
        (lambda p: _table(value=-float("inf")).write_csv(p), [], "that no evaluation gives \\(e.g. -inf;"),
        (lambda p: _table(value=-2.0).write_csv(p), [], "e.g. -2; a score is finite and in \\[-1, 1\\]"),
        (lambda p: _table(value=1.5).write_csv(p), [], "e.g. 1.5;"),
        (lambda p: p.symlink_to(p.parent / "a.csv"), [], "'.*b.csv' is the same file as '.*a.csv'"),
        (lambda p: p.write_bytes((p.parent / "a.csv").read_bytes()), [], "b.csv' holds the same scores as"),
    ],
)
def test_summarize_refuses_what_it_cannot_average(tmp_path, capsys, second, extra, message):
    """Unlike evaluations, damaged files, scores no metric takes (inf, NaN, SSIM outside [-1, 1]) and one
    evaluation given twice (a link, a copy: it would count as a second run that agrees exactly)."""
    import re

    _table().write_csv(tmp_path / "a.csv")
    second(tmp_path / "b.csv")
    line = run_error(capsys, ["summarize", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), *extra])
    assert re.search(message, line), line


# ----------------------------------------------------------------------------- configs (item 14)


def test_duplicate_yaml_keys_are_refused(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("train:\n  steps: 2\n  batch_size: 1\n  steps: 3\n")
    with pytest.raises(ConfigError, match="key 'steps' appears twice \\(line 4\\)"):
        load_config(str(path))
    path.write_text("train:\n  steps: 2\ntrain:\n  steps: 3\n")
    with pytest.raises(ConfigError, match="key 'train' appears twice"):
        load_config(str(path))


def test_tolerance_ssim_images_are_checked(tmp_path, capsys):
    line = run_error(capsys, ["tolerance", "builtin:cpu-doe-net", "--ssim-images", "-1", "--out", str(tmp_path / "t")])
    assert "--ssim-images -1 must be >= 0" in line
    line = run_error(
        capsys, ["tolerance", "builtin:cpu-doe-net", "--ssim-images", "100000", "--out", str(tmp_path / "t")]
    )
    assert "--ssim-images 100000: the run has" in line and not (tmp_path / "t").exists()


# ----------------------------------------------------------------------------- designs (item 14)

R = 1e-3
H2PI = height_2pi_m(550e-9)


@pytest.fixture
def design(tmp_path):
    level = np.arange(16) % 4
    path = tmp_path / "d.npz"
    save_doe(TabulatedRadialDOE(np.linspace(0, R, 17), level * H2PI / 4, R, 550e-9, 4), path, samples=32)
    return path


def _edit(path, target, **changes):
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update({k: np.asarray(v) for k, v in changes.items()})
    np.savez(target, **arrays)
    return target


def test_a_design_round_trips_through_its_level_checks(design):
    doe = load_doe(design)
    assert doe.levels == 4


@pytest.mark.parametrize(
    "changes, expected",
    [
        (lambda d: {"aperture_radius_m": 10e-3}, "exceeds the outermost ring edge"),
        (lambda d: {"height_m": d["height_m"] + 0.3 * H2PI / 4}, "is not one of the 4 levels"),
        (lambda d: {"height_m": d["height_m"] - H2PI}, "is not one of the 4 levels"),
        (lambda d: {"level": d["level"] + 4}, "ring levels must be whole numbers in 0..3"),
        (lambda d: {"level": np.roll(d["level"], 1)}, "has level"),
    ],
)
def test_inconsistent_radial_designs_are_refused(design, tmp_path, capsys, changes, expected):
    with np.load(design) as data:
        bad = _edit(design, tmp_path / "bad.npz", **changes({k: data[k] for k in data.files}))
    with pytest.raises(EdofprojError, match=expected):
        load_doe(bad)
    line = run_error(capsys, ["export-doe", str(bad), "--out", str(tmp_path / "fab")])
    assert "bad.npz" in line and not (tmp_path / "fab").exists()


# ----------------------------------------------------------------------------- outputs (item 14)


def test_an_explicit_out_inside_a_built_in_run_is_refused(tmp_path, capsys):
    inside = BUILTIN_ROOT / "cpu-doe-net" / "eval-by-test"
    line = run_error(capsys, ["evaluate", "builtin:cpu-doe-net", "--out", str(inside), "--quiet"])
    assert "inside a built-in run" in line and not inside.exists()
    line = run_error(capsys, ["export-doe", "builtin:cpu-doe-net", "--out", str(inside)])
    assert "inside a built-in run" in line and not inside.exists()


def test_the_evaluation_set_is_swapped_in_only_when_complete(tmp_path):
    from edofproj.evaluation.output_set import STAGING_PREFIX, staged_output_set

    out = tmp_path / "ev"
    out.mkdir()
    (out / "metrics.csv").write_text("old")
    (out / "report.md").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with staged_output_set(out) as stage:
            (stage / "metrics.csv").write_text("new")
            raise KeyboardInterrupt  # killed before the report is written
    assert {p.name: p.read_text() for p in out.iterdir()} == {"metrics.csv": "old", "report.md": "old"}
    (out / f"{STAGING_PREFIX}abcd1234").mkdir()  # what a kill -9 leaves
    (out / f"{STAGING_PREFIX}abcd1234" / "metrics.csv").write_text("half")
    with pytest.warns(RecoveryWarning, match="interrupted evaluate"):
        with staged_output_set(out) as stage:
            (stage / "figures").mkdir()
            (stage / "figures" / "f.png").write_text("new")
            (stage / "metrics.csv").write_text("new")
            (stage / "report.md").write_text("new")
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "figures",
        "figures/f.png",
        "metrics.csv",
        "report.md",
    ]
    assert (out / "report.md").read_text() == "new"


def test_export_doe_removes_the_staging_a_killed_export_left(design, tmp_path):
    from edofproj.fabrication.export import export_doe

    stale = tmp_path / ".fab.abcd1234.staging"
    stale.mkdir()
    (stale / "masks.gds").write_bytes(b"partial")
    with pytest.warns(RecoveryWarning, match="interrupted export"):
        export_doe(design, tmp_path / "fab")
    assert not stale.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["d.npz", "fab"]


def test_weights_fetch_removes_partial_downloads_of_a_killed_fetch(tmp_path):
    from edofproj.perceptual.weights import BACKBONE_DOWNLOADS, remove_partial_downloads

    name = next(iter(BACKBONE_DOWNLOADS.values())).filename
    partial = tmp_path / f".{name}.tmp-abcd1234.pth"
    partial.write_bytes(b"half")
    foreign = tmp_path / ".other.pth.tmp-abcd1234.pth"  # not ours: torch's cache is shared
    foreign.write_bytes(b"x")
    assert remove_partial_downloads(tmp_path) == [partial]
    assert not partial.exists() and foreign.exists()


# ----------------------------------------------------------------------------- cmd: cameras (item 14)


def _dead_or_zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().split(")")[-1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_camera_command_that_times_out_is_killed_with_its_children(tmp_path):
    from edofproj.procams.devices.cameras import CommandCamera

    pid_file = tmp_path / "child.pid"
    camera = CommandCamera(f"sh -c 'sleep 60 & echo $! > {pid_file}; wait' {{out}}", timeout_s=1.0)
    try:
        with pytest.raises(EdofprojError, match="camera command timed out after 1 s"):
            camera.grab()
    finally:
        camera.close()
    child = int(pid_file.read_text())
    for _ in range(1000):  # SIGKILL is delivered asynchronously: wait for the state, not a time
        if _dead_or_zombie(child):
            break
        os.sched_yield()
        subprocess.run(["true"])
    assert _dead_or_zombie(child)


def test_camera_folders_of_dead_processes_are_removed(tmp_path):
    from edofproj.procams.devices.cameras import CAMERA_FOLDER_PREFIX, remove_stale_camera_folders

    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = tmp_path / f"{CAMERA_FOLDER_PREFIX}{dead.pid}-abcd1234"
    alive = tmp_path / f"{CAMERA_FOLDER_PREFIX}{os.getpid()}-abcd1234"
    for folder in (stale, alive):
        folder.mkdir()
        (folder / "frame.png").write_bytes(b"x")
    assert remove_stale_camera_folders(str(tmp_path)) == [stale]
    assert alive.exists() and not stale.exists()


def test_summarize_refuses_a_folder_given_twice_through_a_link(tmp_path, capsys):
    for name in ("s0", "s1"):
        (tmp_path / name).mkdir()
    _table().write_csv(tmp_path / "s0" / "metrics.csv")
    (tmp_path / "link").symlink_to(tmp_path / "s0")
    line = run_error(capsys, ["summarize", str(tmp_path / "s0"), str(tmp_path / "link")])
    assert "link/metrics.csv" not in line and "'" + str(tmp_path / "link") + "' is the same file as" in line


# ----------------------------------------------------------------------------- screen depths (issue 42, item 7)


def test_the_depths_scored_are_the_ones_stated():
    from edofproj.evaluation.results import format_span_mm
    from edofproj.evaluation.sweep import depth_notes, scored_range_mm

    assert scored_range_mm([250, 300, 500, 800, 900], (300, 800)) == (300, 800)
    assert scored_range_mm([400], (300, 800)) == (400, 400) and format_span_mm(400, 400) == "400"
    assert scored_range_mm([1500, 3000], (300, 800)) == (1500, 3000)
    assert depth_notes([400, 500], (275, 800), (300, 800)) == []
    far, untrained = depth_notes([250, 1500], (275, 800), (300, 800))
    assert far.startswith("depths 250, 1500 mm lie outside the score range 300-800 mm") and "over 300-800" not in far
    assert untrained.startswith("depths 250, 1500 mm lie outside the range the run was trained on, 275-800 mm")
    assert depth_notes([1e4], (275, 800)) == [
        "depths 10000 mm lie outside the range the run was trained on, 275-800 mm: the networks never saw their blur"
    ]


@pytest.mark.parametrize("value", [0.0, -5.0, float("nan"), float("inf"), 1e9, 100_001.0])
def test_a_screen_depth_must_be_a_physical_one(value):
    from edofproj.optics.geometry import check_screen_depths_mm

    with pytest.raises(EdofprojError, match=r"--depth-mm must be screen depths in \[1, 100000\] mm"):
        check_screen_depths_mm(value, "--depth-mm")
    assert check_screen_depths_mm([300, 100_000], "--depth-mm").tolist() == [300, 100_000]


def test_non_physical_depths_are_refused_before_any_work(tmp_path, capsys):
    from edofproj.imaging.image_io import write_image

    write_image(tmp_path / "t.png", torch.rand(3, 16, 16))
    for argv in (
        ["compensate", "builtin:cpu-doe-net", "--image", str(tmp_path / "t.png"), "--depth-mm", "1e9"],
        ["evaluate", "builtin:cpu-doe-net", "--depths-mm", "400,1e9", "--quiet"],
        ["evaluate", "builtin:cpu-doe-net", "--surface", "checker", "--depths-mm", "1e9", "--quiet"],
    ):
        line = run_error(capsys, argv + ["--out", str(tmp_path / "out.png")])
        assert "must be screen depths in [1, 100000] mm, got 1e+09" in line, line
    assert not (tmp_path / "out.png").exists()


def test_images_smaller_than_the_linear_filter_get_advice_the_user_can_follow():
    """The radius of a trained run is fixed (evaluate refuses --set net.*): the advice names the image size."""
    from edofproj.compensation.linear_base import LinearBase

    with pytest.raises(EdofprojError) as refused:
        LinearBase(radius=33)(torch.zeros(1, 3, 24, 32))
    message = str(refused.value)
    assert "at least 34x34 px, got 24x32 (height x width)" in message
    assert "a trained run's radius is fixed: to evaluate, a larger evaluation.image_size" in message


@pytest.mark.slow
def test_evaluate_on_images_too_small_for_the_filter_says_what_evaluate_can_change(tmp_path, capsys):
    argv = ["evaluate", "builtin:cpu-doe-unet", "--set", "evaluation.image_size=[24,32]", "--methods", "doe+net"]
    line = run_error(capsys, argv + ["--depths-mm", "400", "--out", str(tmp_path / "ev"), "--quiet"])
    assert "a larger evaluation.image_size" in line and "use a smaller net.linear_radius" not in line
