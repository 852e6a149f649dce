"""Fault tier: directory locks (one writer per directory) and the clean-up of interrupted writes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings

import pytest

from edofproj.errors import EdofprojError, RecoveryWarning
from edofproj.fileio import TEMP_PATTERN, atomic_path, remove_stale_temp_files, write_text_atomic
from edofproj.locking import LOCK_NAME, DirectoryLock, DirectoryLockedError, directory_lock, read_lock_owner

HOLD_LOCK = textwrap.dedent(
    """
    import sys, time
    from edofproj.locking import DirectoryLock
    lock = DirectoryLock(sys.argv[1], "holder", beside=len(sys.argv) > 2).acquire()
    print("locked", flush=True)
    time.sleep(60)
    """
)


def _holder(directory, beside=False):
    """A child process that takes ``directory``'s lock and sleeps (killed by the test)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(directory)] + (["beside"] if beside else []),
        stdout=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)),
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    return proc


def test_the_lock_file_names_its_owner_and_goes_away_on_release(tmp_path):
    target = tmp_path / "run"
    with directory_lock(target, "edofproj train", "--out") as lock:
        owner = read_lock_owner(target)
        assert owner is not None and owner["pid"] == os.getpid() and owner["command"] == "edofproj train"
        assert lock.held
        (target / "file.txt").write_text("x")
    assert not (target / LOCK_NAME).exists()
    assert (target / "file.txt").is_file()


def test_a_directory_the_lock_created_and_nothing_wrote_is_removed(tmp_path):
    target = tmp_path / "new"
    with pytest.raises(RuntimeError):
        with directory_lock(target):
            raise RuntimeError("the command failed before writing")
    assert not target.exists()


def test_a_second_writer_in_another_process_is_refused_in_one_line(tmp_path):
    target = tmp_path / "run"
    holder = _holder(target)
    try:
        with pytest.raises(DirectoryLockedError) as refused:
            DirectoryLock(target, "edofproj train", "--out").acquire()
        message = str(refused.value)
        assert "\n" not in message
        assert f"PID {holder.pid}" in message and "--out" in message and "holder" in message
    finally:
        holder.kill()
        holder.wait()


def test_a_lock_left_by_a_killed_process_is_taken_over_with_a_warning(tmp_path):
    target = tmp_path / "run"
    holder = _holder(target)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert (target / LOCK_NAME).is_file()  # kill -9 leaves the file behind
    with pytest.warns(RecoveryWarning, match=f"PID {holder.pid}.*no longer runs"):
        lock = DirectoryLock(target, "edofproj train").acquire()
    assert read_lock_owner(target)["pid"] == os.getpid()
    lock.release()


def test_the_same_process_cannot_take_a_held_lock_twice_through_another_object(tmp_path):
    first = DirectoryLock(tmp_path / "d").acquire()
    try:
        with pytest.raises(DirectoryLockedError):
            DirectoryLock(tmp_path / "d").acquire()
    finally:
        first.release()
    with directory_lock(tmp_path / "d"):  # free again
        pass


def test_a_lock_on_a_file_path_is_a_one_line_error(tmp_path):
    path = tmp_path / "file"
    path.write_text("x")
    with pytest.raises(EdofprojError, match="not a directory"):
        DirectoryLock(path).acquire()


def test_a_garbled_lock_file_of_a_dead_writer_is_taken_over(tmp_path):
    (tmp_path / LOCK_NAME).write_text("{not json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to name: taken over silently
        with directory_lock(tmp_path):
            assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()


# ----------------------------------------------------------------------------- interrupted writes


def test_stale_temp_files_of_interrupted_writes_are_removed_and_nothing_else(tmp_path):
    (tmp_path / "checkpoints").mkdir()
    stale = [
        tmp_path / "checkpoints" / ".last.pt.tmp-ab12cd34.pt",  # this version's temporary names
        tmp_path / "checkpoints" / ".step_000004.pt.k3j4h5g6.pt",  # earlier versions' names
        tmp_path / ".config.yaml.tmp-zz_9yy8x.yaml",
        tmp_path / ".doe.npz.tmp-q1w2e3r4.npz.tmp",
    ]
    kept = [tmp_path / "checkpoints" / "last.pt", tmp_path / ".gitignore", tmp_path / LOCK_NAME, tmp_path / "a.txt"]
    for path in stale + kept:
        path.write_bytes(b"x")
    removed = remove_stale_temp_files(tmp_path, recursive=True)
    assert sorted(removed) == sorted(stale)
    assert all(p.exists() for p in kept) and not any(p.exists() for p in stale)


@pytest.mark.parametrize("name, suffix", [("psf.npz", ".npz.tmp"), ("last.pt", None), ("config.yaml", None)])
def test_the_temp_files_of_atomic_writes_are_recognised_as_stale(tmp_path, name, suffix):
    """What ``kill -9`` leaves during a write is exactly what the clean-up removes."""
    with atomic_path(tmp_path / name, suffix=suffix) as tmp:
        tmp.write_bytes(b"partial")
        assert TEMP_PATTERN.match(tmp.name) and TEMP_PATTERN.match(tmp.name).group("target") == name
        assert remove_stale_temp_files(tmp_path) == [tmp]
        tmp.write_bytes(b"complete")  # the writer (were it alive) finishes
    assert (tmp_path / name).read_bytes() == b"complete"


def test_a_write_refused_by_the_system_names_the_target_not_the_temp_file(tmp_path, monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / ".out.txt.tmp-abcdefgh.txt"))

    monkeypatch.setattr("tempfile.mkstemp", refuse)
    with pytest.raises(EdofprojError) as refused:
        write_text_atomic(tmp_path / "out.txt", "x")
    message = str(refused.value)
    assert f"'{tmp_path / 'out.txt'}'" in message and "tmp-" not in message and "writable" in message


def test_a_concurrent_writer_waits_for_nothing_it_is_refused_at_once(tmp_path):
    holder = _holder(tmp_path / "d")
    try:
        clock = time.perf_counter()
        with pytest.raises(DirectoryLockedError):
            DirectoryLock(tmp_path / "d").acquire()
        assert time.perf_counter() - clock < 1.0
    finally:
        holder.kill()
        holder.wait()


# ----------------------------------------------------------------------------- capture folders


def test_a_capture_folder_being_written_is_refused_to_a_second_writer(tmp_path):
    from edofproj.procams.capture_io import atomic_folder

    target = tmp_path / "captures"
    holder = _holder(target, beside=True)
    try:
        with pytest.raises(DirectoryLockedError, match="holder"):
            with atomic_folder(target):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert not target.exists()


def test_unfinished_capture_folders_of_a_killed_writer_are_removed(tmp_path):
    from edofproj.procams.capture_io import atomic_folder

    target = tmp_path / "captures"
    unfinished = [tmp_path / ".captures.ab12cd34", tmp_path / ".captures.old.zz99yy88"]
    other = tmp_path / ".other.ab12cd34"
    for folder in unfinished + [other]:
        folder.mkdir()
        (folder / "x.png").write_bytes(b"x")
    with pytest.warns(RecoveryWarning, match="removed 2 unfinished folder"):
        with atomic_folder(target) as tmp:
            (tmp / "capture.png").write_bytes(b"png")
    assert (target / "capture.png").is_file() and other.is_dir()
    assert not any(f.exists() for f in unfinished)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([".other.ab12cd34", "captures"])  # lock file gone
