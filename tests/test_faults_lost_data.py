"""Fault tier: lost data (issue 42). No output replaces, deletes or mixes into an input; no two
inputs are written under one name; a capture session keeps one camera; an evaluation replaces the
previous one as a whole; a killed video writer's file is cleaned up; a full disk is one line.

The CLI subprocess tests (marked slow) run the hostile tester's cases end to end."""

from __future__ import annotations

import errno
import json
import os
import pathlib
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from edofproj.builtin_runs import resolve_run_dir
from edofproj.cli import main
from edofproj.errors import DiskFullError, EdofprojError
from edofproj.outputs import refuse_colliding_names, refuse_output_over_inputs

HW = (36, 48)  # larger than the built-in network's filter radius (33 px)
RUN = "builtin:cpu-doe-net"


def run_error(capsys, argv) -> str:
    """Run the CLI expecting a user error: exit code 2 and exactly one line on stderr."""
    capsys.readouterr()
    assert main(argv) == 2
    lines = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("edofproj: warning:")]
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: "), lines
    return lines[0]


def snapshot(folder: pathlib.Path) -> dict[str, bytes]:
    """Every file below ``folder`` with its bytes (to show that nothing changed)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def images(folder: pathlib.Path, names=("a.png", "b.png"), seed=0) -> pathlib.Path:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 255, (*HW, 3), dtype=np.uint8))
    return folder


def video(path: pathlib.Path, frames=4) -> pathlib.Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (HW[1], HW[0]))
    rng = np.random.default_rng(1)
    for _ in range(frames):
        writer.write(rng.integers(0, 255, (*HW, 3), dtype=np.uint8))
    writer.release()
    return path


# ----------------------------------------------------------------------------- the rule (item 1)


def test_an_output_may_not_be_contain_or_lie_inside_an_input(tmp_path):
    slides = images(tmp_path / "par" / "in")
    (tmp_path / "link").symlink_to(tmp_path / "par")
    for out, relation in [
        (slides, "is the input"),
        (tmp_path / "par" / "in" / ".." / "in", "is the input"),  # '..' resolved
        (tmp_path / "par", "contains the input"),
        (tmp_path / "link", "contains the input"),  # a symlink to the folder holding the input
        (slides / "out", "lies inside the input"),
        (tmp_path / "link" / "in" / "out", "lies inside the input"),
    ]:
        with pytest.raises(EdofprojError, match=relation):
            refuse_output_over_inputs(out, [("--images", slides)])
    os.link(slides / "a.png", tmp_path / "hard.png")  # one file under two names
    with pytest.raises(EdofprojError, match="is the input"):
        refuse_output_over_inputs(tmp_path / "hard.png", [("--image", slides / "a.png")], file_output=True)
    cwd = os.getcwd()
    try:  # a relative output against an absolute input
        os.chdir(tmp_path / "par")
        with pytest.raises(EdofprojError, match="--out 'in' is the input --images"):
            refuse_output_over_inputs("in", [("--images", slides)])
    finally:
        os.chdir(cwd)
    # allowed: beside the input, a file beside the captures it came from, an input that does not exist
    refuse_output_over_inputs(tmp_path / "par" / "out", [("--images", slides)])
    refuse_output_over_inputs(slides / "calib.npz", [("--captures", slides)], file_output=True)
    refuse_output_over_inputs(tmp_path / "leaves", [("--surface", "leaves")])
    # a holder (a run directory) may hold the output, not be or contain it
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    refuse_output_over_inputs(run / "eval", [("RUN's checkpoints", run / "checkpoints")], holders=[("RUN", run)])
    for out in (run, tmp_path):
        with pytest.raises(EdofprojError, match="whose files are inputs"):
            refuse_output_over_inputs(out, [], holders=[("RUN", run)])


def test_every_writing_command_refuses_to_write_over_its_input(tmp_path, capsys):
    """One line, exit 2, before any work; the inputs are byte for byte as they were."""
    slides = images(tmp_path / "slides")
    images(tmp_path / "par" / "in")
    (tmp_path / "par" / "notes.txt").write_text("unrelated\n")
    video(tmp_path / "a.avi")
    assert (
        main(
            ["procams", "patterns", "--width", "32", "--height", "24", "--dots", "3x4", "--out", str(tmp_path / "pat")]
        )
        == 0
    )
    doe = tmp_path / "design" / "doe.npz"
    doe.parent.mkdir()
    shutil.copy(resolve_run_dir(RUN) / "doe.npz", doe)
    before = snapshot(tmp_path)
    t = str(tmp_path)
    # fmt: off
    cases = [
        ["compensate", RUN, "--images", f"{t}/slides", "--depth-mm", "400", "--out", f"{t}/slides", "--overwrite"],
        ["compensate", RUN, "--images", f"{t}/par/in", "--depth-mm", "400", "--out", f"{t}/par", "--overwrite"],
        ["compensate", RUN, "--images", f"{t}/slides", "--depth-mm", "400", "--out", f"{t}/slides/u"],
        ["compensate", RUN, "--video", f"{t}/a.avi", "--depth-mm", "400", "--out", f"{t}/a.avi", "--overwrite"],
        ["compensate", RUN, "--image", f"{slides}/a.png", "--depth-mm", "400", "--out", f"{slides}/a.png"],
        ["compensate", RUN, "--image", f"{slides}/a.png", "--depth-mm", "400", "--out", f"{t}/o.png",
         "--preview", f"{slides}/a.png"],
        ["procams", "simulate", "--patterns", f"{t}/pat", "--out", f"{t}/pat", "--overwrite", "--depth-mm", "400"],
        ["procams", "capture", "--patterns", f"{t}/pat", "--out", f"{t}/pat/cap", "--camera", "opencv:0",
         "--display", "memory"],
        ["procams", "rectify", f"{t}/slides", "--calib", "c.npz", "--out", f"{t}/slides"],
        ["procams", "evaluate", "--targets", f"{t}/slides", "--captures", f"{t}/par", "--calib", "c.npz", "--out", t,
         "--overwrite"],
        ["procams", "estimate-psf", "--patterns", f"{t}/pat", "--captures", f"{t}/par", "--calib", f"{doe}",
         "--out", f"{doe}"],
        ["render", "--image", f"{slides}/a.png", "--doe", "lens", "--depth-mm", "400", "--out", f"{slides}/a.png"],
        ["evaluate", RUN, "--images", f"{t}/slides", "--out", f"{t}/slides"],
        ["evaluate", RUN, "--images", f"{t}/par", "--out", f"{t}/par/in"],
        ["export-doe", str(doe), "--out", str(doe.parent)],
        ["psf", "--doe", str(doe), "--depth-mm", "400", "--out", str(doe)],
        ["finetune", RUN, "--psfs", str(doe), "--out", str(doe.parent)],
        ["scene", "render", "--scene", "wall", "--doe", "lens", "--image", f"{slides}/a.png", "--out", f"{slides}/a.png"],
    ]
    # fmt: on
    for argv in cases:
        line = run_error(capsys, argv)
        assert any(word in line for word in ("is the input", "contains the input", "lies inside the input")), (
            argv,
            line,
        )
    assert snapshot(tmp_path) == before
    assert not any(".edofproj.lock" in p.name for p in tmp_path.rglob(".*"))


# ----------------------------------------------------------------------------- colliding names (item 2)


def test_two_inputs_that_give_one_output_name_are_refused_before_any_work(tmp_path, capsys):
    from edofproj.application.offline import FolderSink, open_frames

    folder = images(tmp_path / "xy", names=("x.png", "x.jpg", "y.png"))
    with pytest.raises(EdofprojError, match="'x.jpg' and 'x.png' would both be written as 'x.png'"):
        open_frames(images=str(folder))
    line = run_error(
        capsys, ["compensate", RUN, "--images", str(folder), "--depth-mm", "400", "--out", f"{tmp_path}/u"]
    )
    assert "would both be written as 'x.png'" in line and not (tmp_path / "u").exists()
    line = run_error(capsys, ["procams", "rectify", str(folder), "--calib", "c.npz", "--out", f"{tmp_path}/r"])
    assert "would both be written as 'x.png'" in line
    refuse_colliding_names([pathlib.Path("x.png"), pathlib.Path("X.png")], lambda p: p.name)  # distinct names
    with FolderSink(tmp_path / "sink") as sink:  # the sink itself never replaces a frame
        sink.write("x", np.zeros((*HW, 3), np.float32))
        with pytest.raises(EdofprojError, match="both be written as 'x.png'"):
            sink.write("x", np.ones((*HW, 3), np.float32))


# ----------------------------------------------------------------------------- one camera per session (item 3)


@pytest.fixture(scope="module")
def virtual_session(tmp_path_factory):
    """Patterns, a white screen's and an object's simulated captures (virtual cameras)."""
    root = tmp_path_factory.mktemp("session")
    assert main(["procams", "patterns", "--width", "48", "--height", "36", "--bernoulli", "2", "--dots", "4x6",
                 "--color-levels", "2", "--out", str(root / "pat")]) == 0  # fmt: skip
    base = [
        "procams",
        "simulate",
        "--patterns",
        str(root / "pat"),
        "--depth-mm",
        "400",
        "--doe",
        "lens",
        "--window",
        "9",
    ]
    assert main(base + ["--out", str(root / "white")]) == 0
    assert main(base + ["--out", str(root / "object"), "--surface", "checker"]) == 0
    return root


def _interrupted_capture(root, out, camera_spec, count=5):
    from edofproj.procams.devices import open_camera, open_display
    from edofproj.procams.session import capture_patterns

    display = open_display("memory")
    camera = open_camera(camera_spec, display=display)
    return capture_patterns(root / "pat", out, display, camera, depth_mm=400.0, stop_after=count)


def test_a_capture_session_is_resumed_only_with_its_camera(virtual_session, tmp_path, capsys):
    root = virtual_session
    out = tmp_path / "cap"
    _interrupted_capture(root, out, f"virtual:{root / 'white'}")
    before = snapshot(out)
    capture = ["procams", "capture", "--patterns", str(root / "pat"), "--out", str(out), "--display", "memory"]
    line = run_error(capsys, capture + ["--camera", f"virtual:{root / 'object'}", "--depth-mm", "400"])
    assert "a session is tied to its camera" in line and f"virtual:{root / 'white'}" in line
    assert snapshot(out) == before
    assert main(capture + ["--camera", f"virtual:{root / 'white'}", "--depth-mm", "400"]) == 0
    info = json.loads((out / "captures.json").read_text())
    assert info["complete"] and info["cameras"] == {f"virtual:{root / 'white'}": info["total"]}
    # a complete session asked again with another camera: nothing to capture, the record keeps its camera
    assert main(capture + ["--camera", f"virtual:{root / 'object'}", "--depth-mm", "400"]) == 0
    assert json.loads((out / "captures.json").read_text())["camera"]["spec"] == f"virtual:{root / 'white'}"


def test_calibrate_refuses_a_capture_folder_of_two_cameras(virtual_session, tmp_path, capsys):
    """A folder whose record names two cameras (assembled from two sessions by hand, or resumed
    with another camera by an earlier edofproj, which recorded only the last one) is not calibrated."""
    root = virtual_session
    out = tmp_path / "cap"
    shutil.copytree(root / "white", out)
    info = json.loads((out / "captures.json").read_text())
    (out / "captures.json").write_text(json.dumps({**info, "cameras": {"virtual:white": 9, "virtual:object": 10}}))
    argv = [
        "procams",
        "calibrate",
        "--patterns",
        str(root / "pat"),
        "--captures",
        str(out),
        "--out",
        f"{tmp_path}/c.npz",
    ]
    line = run_error(capsys, argv)
    assert "mixes the captures of 2 cameras" in line and not (tmp_path / "c.npz").exists()


# ----------------------------------------------------------------------------- evaluations (item 9)


def test_a_new_evaluation_replaces_the_previous_set_as_a_whole(tmp_path):
    from edofproj.evaluation.output_set import EVALUATION_FILES, staged_output_set

    out = tmp_path / "eval"
    (out / "figures").mkdir(parents=True)
    for name in ("surface_metrics.csv", "surface_summary.md", "figures/eval_surfaces.png", "metrics.csv"):
        (out / name).write_text("previous\n")
    (out / "notes.txt").write_text("the user's\n")
    (out / "figures" / "loss_curve.png").write_text("a run's figure\n")
    with staged_output_set(out) as stage:
        (stage / "metrics.csv").write_text("new\n")
        (stage / "report.md").write_text("new\n")
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()) == [
        "figures/loss_curve.png",
        "metrics.csv",
        "notes.txt",
        "report.md",
    ]
    assert (out / "metrics.csv").read_text() == "new\n"
    # every file name the evaluations write is in the set that is replaced
    from edofproj.evaluation.pipeline import METRICS_NAME, TILTED_METRICS_NAME
    from edofproj.evaluation.scenes import SCENE_METRICS_NAME
    from edofproj.evaluation.surfaces import SURFACE_FIGURE_NAME, SURFACE_METRICS_NAME, SURFACE_SUMMARY_NAME
    from edofproj.reporting.scenes import SCENE_SUMMARY_NAME
    from edofproj.reporting.writeup import REPORT_HTML_NAME, REPORT_MD_NAME, SUMMARY_NAME

    names = [METRICS_NAME, TILTED_METRICS_NAME, SCENE_METRICS_NAME, SURFACE_METRICS_NAME, SURFACE_SUMMARY_NAME]
    names += [SCENE_SUMMARY_NAME, REPORT_HTML_NAME, REPORT_MD_NAME, SUMMARY_NAME]
    assert set(names) <= set(EVALUATION_FILES) and f"figures/{SURFACE_FIGURE_NAME}".startswith("figures/eval_")


# ----------------------------------------------------------------------------- video (item 10)


def test_a_killed_video_writers_temporary_file_is_removed_by_the_next(tmp_path):
    from edofproj.application.offline import VideoSink

    stale = tmp_path / ".show.avi.tmp-abcd1234.avi"
    stale.write_bytes(b"half a video")
    other = tmp_path / ".other.avi.tmp-abcd1234.avi"  # another output's: not this writer's to remove
    other.write_bytes(b"x")
    with pytest.warns(UserWarning, match="removed 1 unfinished video"):
        with VideoSink(tmp_path / "show.avi", 10, HW) as sink:
            lock = json.loads((tmp_path / ".show.avi.edofproj.lock").read_text())
            assert lock["command"] == "edofproj compensate"
            sink.write("f", np.zeros((*HW, 3), np.float32))
    assert not stale.exists() and other.exists() and (tmp_path / "show.avi").is_file()
    assert not (tmp_path / ".show.avi.edofproj.lock").exists()


def test_a_frame_rate_the_container_cannot_hold_is_refused(tmp_path, capsys):
    from edofproj.application.offline import VIDEO_FPS_RANGE, VideoSink

    low, high = VIDEO_FPS_RANGE
    for fps in (1e9, 1001.0, 0.001):
        with pytest.raises(EdofprojError, match="frame rate must lie in"):
            VideoSink(tmp_path / "v.avi", fps, HW)
    for name, fps in (("high.avi", high), ("high.mp4", high), ("low.avi", low)):  # the bounds are stored as given
        with VideoSink(tmp_path / name, fps, HW) as sink:
            for _ in range(2):
                sink.write("f", np.zeros((*HW, 3), np.float32))
        capture = cv2.VideoCapture(str(tmp_path / name))
        assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(fps, rel=1e-4)
        capture.release()
    folder = images(tmp_path / "in")
    line = run_error(
        capsys,
        ["compensate", RUN, "--images", str(folder), "--depth-mm", "400", "--out", f"{tmp_path}/u", "--fps", "12"],
    )
    assert "--fps goes with a video output" in line
    line = run_error(
        capsys,
        ["compensate", RUN, "--images", str(folder), "--depth-mm", "400", "--out", f"{tmp_path}/u.avi", "--fps", "1e9"],
    )
    assert "must lie in 0.01-1000 frames/s" in line and not (tmp_path / "u.avi").exists()


def test_a_video_whose_end_is_lost_says_how_many_frames_decode(tmp_path, monkeypatch):
    """The frames of a full disk are lost at the end, while the AVI header still announces all of
    them: the read-back decodes every frame, and says how many do."""
    from edofproj.application import offline

    real = cv2.VideoWriter

    class LosingTheEnd:
        def __init__(self, path, *args):
            self.path, self.writer = path, real(path, *args)

        def __getattr__(self, name):
            return getattr(self.writer, name)

        def release(self):
            self.writer.release()
            data = pathlib.Path(self.path).read_bytes()
            pathlib.Path(self.path).write_bytes(data[: int(0.6 * len(data))])

    monkeypatch.setattr(offline.cv2, "VideoWriter", LosingTheEnd)
    rng = np.random.default_rng(0)
    with pytest.raises(EdofprojError) as error:
        with offline.VideoSink(tmp_path / "v.avi", 10, HW) as sink:
            for _ in range(20):
                sink.write("f", rng.uniform(0, 1, (*HW, 3)).astype(np.float32))
    message = str(error.value)
    assert "of the 20 frames written decode" in message and "20 of the 20" not in message
    assert [p.name for p in tmp_path.iterdir()] == []


# ----------------------------------------------------------------------------- a full disk (item 12)


def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.fixture
def full_disk(monkeypatch):
    """Every file write of edofproj (atomic writes: bytes, text, NumPy archives) fails with ENOSPC."""
    monkeypatch.setattr(pathlib.Path, "write_bytes", _no_space)
    monkeypatch.setattr(pathlib.Path, "write_text", _no_space)
    monkeypatch.setattr(np, "savez_compressed", _no_space)


def _disk_full_line(capsys, argv) -> str:
    line = run_error(capsys, argv)
    assert "is full" in line and "MB free" in line, line
    return line


def test_a_full_disk_is_one_line_that_says_what_was_kept(tmp_path, capsys, virtual_session, full_disk):
    t = str(tmp_path)
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.full((*HW, 3), 128, np.uint8))
    line = _disk_full_line(
        capsys, ["render", "--image", str(image), "--doe", "lens", "--depth-mm", "400", "--out", f"{t}/o.png"]
    )
    assert "nothing was written" in line and not (tmp_path / "o.png").exists()
    line = _disk_full_line(
        capsys, ["psf", "--doe", "lens", "--depth-mm", "400", "--window", "9", "--out", f"{t}/p.npz"]
    )
    assert "nothing was written" in line
    root = virtual_session
    argv = [
        "procams",
        "calibrate",
        "--patterns",
        str(root / "pat"),
        "--captures",
        str(root / "white"),
        "--out",
        f"{t}/c.npz",
    ]
    line = _disk_full_line(capsys, argv)
    assert "nothing was written" in line
    line = _disk_full_line(
        capsys, ["procams", "patterns", "--width", "32", "--height", "24", "--dots", "3x4", "--out", f"{t}/pat"]
    )
    assert "nothing was written" in line
    folder = images(tmp_path / "in")
    (tmp_path / "u").mkdir()
    with open(tmp_path / "u" / "previous.png", "wb") as handle:  # (Path.write_bytes is the full disk's)
        handle.write(b"the previous show")
    argv = ["compensate", RUN, "--images", str(folder), "--depth-mm", "400", "--out", f"{t}/u", "--overwrite"]
    line = _disk_full_line(capsys, argv)
    assert (
        f"the previous '{t}/u' is kept" in line
        and (tmp_path / "u" / "previous.png").read_bytes() == b"the previous show"
    )
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == [], leftovers  # no temporary folder, no lock file


def test_an_evaluation_on_a_full_disk_keeps_the_previous_results(tmp_path, monkeypatch):
    from edofproj.evaluation.output_set import staged_output_set

    out = tmp_path / "eval"
    out.mkdir()
    (out / "metrics.csv").write_text("previous\n")
    with pytest.raises(DiskFullError, match=f"the previous results in '{out}' are kept"):
        with staged_output_set(out) as stage:
            (stage / "report.md").write_text("new\n")
            monkeypatch.setattr(pathlib.Path, "write_text", _no_space)
            (stage / "metrics.csv").write_text("new\n")
    monkeypatch.undo()
    assert (
        sorted(p.name for p in out.iterdir()) == ["metrics.csv"] and (out / "metrics.csv").read_text() == "previous\n"
    )


def test_a_lock_that_cannot_be_written_leaves_no_lock_file(tmp_path, monkeypatch):
    from edofproj import locking
    from edofproj.procams.capture_io import atomic_folder

    real_write = os.write

    def write(fd, data):
        if os.readlink(f"/proc/self/fd/{fd}").endswith(locking.LOCK_NAME):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(locking.os, "write", write)
    with pytest.raises(DiskFullError, match="is full.*no lock file is left"):
        with atomic_folder(tmp_path / "pat"):
            pass
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- modes and labels (items 16, 17)


def test_output_folders_get_the_users_mode_and_their_lock_names_the_command(tmp_path):
    from edofproj.application.offline import FolderSink

    previous = os.umask(0o022)
    try:
        with FolderSink(tmp_path / "show") as sink:
            lock = json.loads((tmp_path / ".show.edofproj.lock").read_text())
            sink.write("a", np.zeros((*HW, 3), np.float32))
    finally:
        os.umask(previous)
    assert lock["command"] == "edofproj compensate"
    assert (tmp_path / "show").stat().st_mode & 0o777 == 0o755
    assert (tmp_path / "show" / "a.png").stat().st_mode & 0o777 == 0o644


# ----------------------------------------------------------------------------- end to end (CLI subprocesses)


def _cli(*argv, cwd) -> subprocess.CompletedProcess:
    script = "import sys; from edofproj.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True, cwd=cwd)


def _refused(result: subprocess.CompletedProcess, words: str) -> None:
    errors = [line for line in result.stderr.strip().splitlines() if not line.startswith("edofproj: warning:")]
    assert result.returncode == 2 and len(errors) == 1 and words in errors[0], result.stderr


@pytest.mark.slow
def test_cli_overwrite_never_deletes_an_input(tmp_path):
    images(tmp_path / "slides")
    images(tmp_path / "par" / "in")
    (tmp_path / "par" / "notes.txt").write_text("unrelated\n")
    video(tmp_path / "a.avi")
    assert (
        _cli(
            "procams", "patterns", "--width", "32", "--height", "24", "--dots", "3x4", "--out", "pat", cwd=tmp_path
        ).returncode
        == 0
    )
    before = snapshot(tmp_path)
    compensate = ["compensate", RUN, "--depth-mm", "400", "--overwrite"]
    _refused(_cli(*compensate, "--images", "slides", "--out", "slides", cwd=tmp_path), "is the input --images")
    _refused(_cli(*compensate, "--images", "par/in", "--out", "par", cwd=tmp_path), "contains the input --images")
    _refused(_cli(*compensate, "--video", "a.avi", "--out", "./a.avi", cwd=tmp_path), "is the input --video")
    simulate = ["procams", "simulate", "--patterns", "pat", "--out", "pat", "--overwrite", "--depth-mm", "400"]
    _refused(_cli(*simulate, cwd=tmp_path), "is the input --patterns")
    assert snapshot(tmp_path) == before


@pytest.mark.slow
def test_cli_colliding_output_names_are_refused(tmp_path):
    images(tmp_path / "xy", names=("x.png", "x.jpg"))
    result = _cli("compensate", RUN, "--images", "xy", "--depth-mm", "400", "--out", "xy_u", cwd=tmp_path)
    _refused(result, "would both be written as 'x.png'")
    assert not (tmp_path / "xy_u").exists()


@pytest.mark.slow
def test_cli_a_session_keeps_its_camera(virtual_session, tmp_path):
    root = virtual_session
    _interrupted_capture(root, tmp_path / "cap", f"virtual:{root / 'white'}")
    capture = ["procams", "capture", "--patterns", str(root / "pat"), "--out", "cap", "--display", "memory"]
    _refused(
        _cli(*capture, "--camera", f"virtual:{root / 'object'}", "--depth-mm", "400", cwd=tmp_path),
        "tied to its camera",
    )
    info = json.loads((tmp_path / "cap" / "captures.json").read_text())
    assert info["camera"]["spec"] == f"virtual:{root / 'white'}" and not info["complete"]
    assert _cli(*capture, "--camera", f"virtual:{root / 'white'}", "--depth-mm", "400", cwd=tmp_path).returncode == 0
    calibrate = ["procams", "calibrate", "--patterns", str(root / "pat"), "--captures", "cap", "--out", "c.npz"]
    assert _cli(*calibrate, cwd=tmp_path).returncode == 0
    info = json.loads((tmp_path / "cap" / "captures.json").read_text())
    (tmp_path / "cap" / "captures.json").write_text(
        json.dumps({**info, "cameras": {**info["cameras"], "virtual:x": 1}})
    )
    _refused(_cli(*calibrate[:-1], "c2.npz", cwd=tmp_path), "mixes the captures of 2 cameras")


def test_any_other_write_that_meets_a_full_disk_is_one_line(tmp_path, capsys, monkeypatch):
    """A write outside the atomic helpers (a library writing directly) reaches the CLI as OSError
    ENOSPC: one line naming the file and its disk, no traceback."""
    from edofproj.commands import render

    def writes_on_a_full_disk(args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "o.png"))

    monkeypatch.setattr(render, "run", writes_on_a_full_disk)
    line = run_error(capsys, ["render", "--image", "a.png", "--doe", "lens", "--out", str(tmp_path / "o.png")])
    assert f"cannot write '{tmp_path / 'o.png'}': the disk of '/" in line and "the command stopped there" in line
