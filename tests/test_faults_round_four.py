"""Fault tier, round four (issue 60): the hostile tester's cases outside the structured-light
commands, each through the command line as reported, each failing on the code before its fix.

Lost data: an output option over a capture a lab manifest names (item 1), an export into a run's
``checkpoints/`` (item 2), the temporary file of a killed export (item 7). Silent wrong results:
``summarize`` of a table with a repeated row (item 5), ``tune-classic --values ""`` (item 8). A
machine brought down: one huge ``--image`` (item 11). Messages that say what to do (item 12).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from edofproj.builtin_runs import builtin_run_dir
from edofproj.cli import main

RUN = "builtin:cpu-doe-net"


def error_line(capsys, argv) -> str:
    """Run the CLI expecting a user error: exit code 2 and exactly one line on stderr (warnings aside)."""
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2, argv
    lines = [line for line in capsys.readouterr().err.splitlines() if line and "warning:" not in line]
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: "), lines
    return lines[0]


def image(path: Path, hw=(48, 64)) -> Path:
    cv2.imwrite(str(path), (np.random.default_rng(0).random((*hw, 3)) * 255).astype(np.uint8))
    return path


# ----------------------------------------------------------------------------- lost data (items 1, 2, 7)


def test_psf_map_figure_over_a_capture_the_lab_names_is_refused(tmp_path, capsys):
    """``procams psf-map ... --figure CAPTURE`` replaced the dot capture it reads (exit 0): the capture
    is named by the lab manifest, not by an option."""
    from edofproj.procams.lab_manifest import LAB_FORMAT

    capture = image(tmp_path / "dots.png", (24, 32))
    dots = {"name": "dots", "kind": "dots", "spacing_px": [8, 8], "origin_px": [0, 0], "files": {"list": ["dots.png"]}}
    lab = {"format": LAB_FORMAT, "version": 1, "projector": {"height": 24, "width": 32}, "sequences": [dots]}
    (tmp_path / "lab.json").write_text(json.dumps(lab))
    (tmp_path / "map.npz").write_bytes(b"never read: the outputs are refused first")
    before = capture.read_bytes()
    line = error_line(
        capsys,
        ["procams", "psf-map", "--lab", tmp_path / "lab.json", "--dots", "dots", "--map", tmp_path / "map.npz",
         "--out", tmp_path / "p.npz", "--figure", capture],
    )  # fmt: skip
    assert "--figure" in line and "is the input --lab's 'dots' capture" in line, line
    assert capture.read_bytes() == before and not (tmp_path / "p.npz").exists()


def test_export_into_the_runs_checkpoints_is_refused_and_its_checkpoint_kept(tmp_path, capsys):
    """``export RUN --out RUN/checkpoints/last.pt`` replaced the run's newest checkpoint, its own input."""
    run = tmp_path / "run"
    shutil.copytree(builtin_run_dir("cpu-doe-net"), run)
    last = run / "checkpoints" / "last.pt"
    before = last.read_bytes()
    line = error_line(capsys, ["export", run, "--format", "torchscript", "--out", last, "--height", 64, "--width", 64])
    assert "inside the checkpoints of the run" in line and "only training writes" in line, line
    assert last.read_bytes() == before and [p.name for p in last.parent.iterdir()] == ["last.pt"]


def test_bench_csv_over_the_runs_config_is_refused(tmp_path, capsys):
    """``bench --run RUN --csv RUN/config.yaml`` replaced the run's configuration with its timings."""
    run = tmp_path / "run"
    shutil.copytree(builtin_run_dir("cpu-doe-net"), run)
    before = (run / "config.yaml").read_bytes()
    argv = ["bench", "--run", run, "--sizes", "64x64", "--repeats", 1, "--warmup", 0, "--no-onnx"]
    line = error_line(capsys, [*argv, "--csv", run / "config.yaml"])
    assert "--csv" in line and "is the input --run's config.yaml" in line, line
    assert (run / "config.yaml").read_bytes() == before


#: An export that stops, blocked, once its temporary file is written (then the test kills it).
BLOCKED_EXPORT = textwrap.dedent(
    """
    import sys
    import edofproj.compensation.export as export

    write = export._write_torchscript

    def write_then_block(net, path, height, width):
        write(net, path, height, width)
        print(path, flush=True)  # the temporary file exists: the test may kill us now
        sys.stdin.read()  # until killed

    export._write_torchscript = write_then_block
    from edofproj.cli import main

    sys.exit(main(sys.argv[1:]))
    """
)


def test_the_next_export_removes_the_temporary_file_of_a_killed_one(tmp_path, capsys):
    """A ``kill -9`` during ``export`` left ``.NAME.tmp-*.pt`` for good. The next export of the same
    file removes it; while the first still runs, its file is its own (a second export is refused)."""
    out = tmp_path / "exports" / "net.pt"
    argv = [
        "export",
        RUN,
        "--format",
        "torchscript",
        "--out",
        str(out),
        "--height",
        "64",
        "--width",
        "64",
        "--no-verify",
    ]
    child = subprocess.Popen(
        [sys.executable, "-c", BLOCKED_EXPORT, *argv],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, OMP_NUM_THREADS="1"),
    )
    try:
        temporary = Path(child.stdout.readline().strip())  # waits for the state, not for a clock
        assert temporary.is_file() and temporary.name.startswith(".net.pt.tmp-"), (temporary, child.stderr.read())
        unrelated = out.parent / ".other.pt.tmp-abcdefgh.pt"  # another file's temporary: never touched
        unrelated.write_bytes(b"x")
        line = error_line(capsys, argv)  # the live writer holds the file
        assert "locked" in line or "is being written" in line or "PID" in line, line
        assert temporary.is_file()
    finally:
        child.send_signal(signal.SIGKILL)
        child.communicate()
    assert child.returncode == -signal.SIGKILL and temporary.is_file() and not out.exists()
    capsys.readouterr()
    with pytest.warns(Warning, match="removed 1 unfinished file"):
        assert main(argv) == 0
    assert out.is_file() and not temporary.exists() and unrelated.is_file()
    assert sorted(p.name for p in out.parent.iterdir()) == [".other.pt.tmp-abcdefgh.pt", "net.pt"]


# ----------------------------------------------------------------------------- silent wrong results (5, 8)


def test_summarize_refuses_a_repeated_method_depth_image_row(tmp_path, capsys):
    """One extra row with SSIM 0 moved a mean (it was averaged in): refused, naming the first repeat."""
    header = "method,depth_mm,image,psnr,ssim,ms_ssim\n"
    for seed in (0, 1):
        rows = "".join(f"{m},{z},a.png,30,0.8{seed},0.9\n" for m in ("doe+net", "doe") for z in (300, 500))
        (tmp_path / f"e{seed}").mkdir()
        (tmp_path / f"e{seed}" / "metrics.csv").write_text(header + rows + ("doe+net,300,a.png,30,0,0.9\n" * seed))
    line = error_line(capsys, ["summarize", tmp_path / "e0", tmp_path / "e1"])
    assert "line 6 repeats line 2 (method doe+net, depth_mm 300, image a.png)" in line, line
    assert "remove the repeated row" in line


@pytest.fixture
def no_sweep(monkeypatch):
    """``tune-classic``'s sweep replaced by a failure: a refusal must come before any scoring."""
    import edofproj.evaluation.classic_optics as classic_optics

    def sweep(*args, **kwargs):
        raise AssertionError("the sweep ran")

    monkeypatch.setattr(classic_optics, "sweep_classic_element", sweep)


def test_tune_classic_refuses_empty_values_instead_of_the_default_sweep(tmp_path, capsys, no_sweep):
    line = error_line(capsys, ["tune-classic", "--element", "cubic", "--values", "", "--out", tmp_path / "t"])
    assert "--values is empty" in line and "leave --values out for the default sweep" in line, line
    assert not (tmp_path / "t").exists()


def test_tune_classic_names_the_largest_cubic_strength_any_sampling_resolves(tmp_path, capsys, no_sweep):
    """``--values 1e9`` printed a garbled sampling message. The cubic phase ``2 pi alpha (x^3 + y^3)``
    (x, y in units of R) changes by ``2 pi 3 alpha (D / M) / R = 12 pi alpha / M`` between samples at
    the rim; at most pi/2 with the finest sampling M = 65536: alpha <= 65536 / 24 = 2730.67 waves."""
    line = error_line(capsys, ["tune-classic", "--element", "cubic", "--values", "5,1e9", "--out", tmp_path / "t"])
    assert "a cubic alpha of 1e+09 waves is more than any pupil sampling resolves" in line, line
    largest = float(line.split("the largest usable alpha is ")[1].split(" waves")[0])
    assert 65536 / 24 - 0.01 <= largest <= 65536 / 24, line


# ----------------------------------------------------------------------------- a machine brought down (11)


def test_one_huge_image_to_compensate_is_refused_from_its_header(tmp_path, capsys, monkeypatch):
    """``compensate --image`` had no memory check of its own (``--images`` had): a 20000x20000 PNG of
    1.1 MB took 22 GB. With 150 MB available, a 1000x1000 image reads (36 MB) but its compensation
    (the simulated screen, 80 B/px of the padded frame, and the network, 128 B/px) does not fit."""
    monkeypatch.setenv("EDOFPROJ_MEMORY_BYTES", str(150e6))
    target = image(tmp_path / "big.png", (1000, 1000))
    line = error_line(capsys, ["compensate", RUN, "--image", target, "--depth-mm", 500, "--out", tmp_path / "o.png"])
    assert "compensating the 1000x1000 (height x width) image" in line and "scale the image down" in line, line
    assert not (tmp_path / "o.png").exists()
    folder = tmp_path / "show"
    folder.mkdir()
    shutil.copy(target, folder / "big.png")
    line = error_line(
        capsys,
        ["compensate", RUN, "--images", folder, "--batch", 1, "--depth-mm", 500, "--out", tmp_path / "shown"],
    )
    assert "batches of 1 frames" in line and "lower --batch" not in line and "scale the frames down" in line, line


def test_one_huge_image_on_a_scene_is_refused_from_its_header(tmp_path, capsys, monkeypatch):
    """``scene render --image`` had no memory check either: with 250 MB available a 1000x1000 image reads
    (36 MB) and the lens's PSFs fit (175 MiB), its projection on the scene's 8 depth layers does not."""
    monkeypatch.setenv("EDOFPROJ_MEMORY_BYTES", str(250e6))
    target = image(tmp_path / "big.png", (1000, 1000))
    argv = [
        "scene",
        "render",
        "--scene",
        "sphere_wall",
        "--doe",
        "lens",
        "--image",
        target,
        "--out",
        tmp_path / "s.png",
    ]
    line = error_line(capsys, argv)
    assert "rendering the 1000x1000 (height x width) image" in line and "scale the image down" in line, line
    assert not (tmp_path / "s.png").exists()


# ----------------------------------------------------------------------------- one line that says what to do (12)


def test_a_method_without_its_trained_run_says_so(tmp_path, capsys):
    line = error_line(
        capsys,
        ["compensate", RUN, "--method", "multifocal+net", "--image", image(tmp_path / "a.png"), "--depth-mm", 500,
         "--out", tmp_path / "o.png"],
    )  # fmt: skip
    assert "needs no" not in line and "needs a trained run of its own, and there is none at" in line, line
    assert "edofproj train" in line and "--baselines" in line


def test_a_depth_of_a_nanometre_is_refused_with_its_value(tmp_path, capsys):
    target = image(tmp_path / "a.png")
    for argv in (
        ["compensate", RUN, "--image", target, "--depth-mm", "1e-9", "--out", tmp_path / "o.png"],
        ["psf", "--doe", "lens", "--depth-mm", "1e-9", "--out", tmp_path / "p.npz"],
    ):
        line = error_line(capsys, argv)
        assert "got 1e-09" in line and "depths are in mm" in line and "[0.0]" not in line, line


def test_libpng_prints_nothing_of_its_own(tmp_path, capfd):
    """A damaged PNG: one line, ours; libpng's own ``libpng error: ...`` (written to descriptor 2) is not shown."""
    data = bytearray(cv2.imencode(".png", np.zeros((48, 64, 3), np.uint8))[1].tobytes())
    data[data.find(b"IDAT") + 10] ^= 0xFF
    (tmp_path / "damaged.png").write_bytes(bytes(data))
    capfd.readouterr()
    argv = [
        "render",
        "--image",
        tmp_path / "damaged.png",
        "--doe",
        "lens",
        "--depth-mm",
        500,
        "--out",
        tmp_path / "o.png",
    ]
    assert main([str(a) for a in argv]) == 2
    err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert err == [f"edofproj: error: cannot read image '{tmp_path / 'damaged.png'}': not a readable "
                   "PNG/JPEG/TIFF/BMP file or truncated"], err  # fmt: skip
    from edofproj.imaging.image_io import read_image_array

    print("still shown", file=sys.stderr, flush=True)  # other output on descriptor 2 goes on
    assert capfd.readouterr().err == "still shown\n"
    assert read_image_array(image(tmp_path / "fine.png")).shape == (48, 64, 3)


def test_a_negative_looking_frame_size_reaches_bench(capsys):
    """``bench --sizes -5x10`` got argparse's 'expected one argument': the value is the command's to judge."""
    line = error_line(capsys, ["bench", "--sizes", "-5x10"])
    assert "frame size '-5x10' must be positive pixel counts HEIGHTxWIDTH, e.g. 600x800" in line, line


def test_a_reversed_range_says_which_way_it_goes(tmp_path, capsys):
    line = error_line(capsys, ["evaluate", RUN, "--depths-mm", "800:300:100", "--out", tmp_path / "ev"])
    assert "'800:300:100' runs down from 800 to 300" in line and "e.g. 300:800:100" in line, line
