"""Fault tier: files a user hands the tool (calibrations, pattern manifests, capture sessions, scenes)
are validated field by field, in one place per format, and refused in one line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.errors import EdofprojError, RecoveryWarning
from edofproj.procams.calibration import ProCamsCalibration, calibrate
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.devices.cameras import VirtualCamera
from edofproj.procams.devices.displays import MemoryDisplay
from edofproj.procams.patterns import MANIFEST_NAME, PatternManifest, PatternSpec, build_pattern_set, manifest_json_text
from edofproj.procams.session import capture_patterns
from edofproj.procams.virtual import CAPTURE_INFO_JSON
from virtual_rigs import delta_psf, straight_rig

HW = (16, 20)


def run_error(capsys, argv) -> str:
    """Run the CLI expecting a user error: exit code 2 and exactly one line on stderr."""
    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: "), lines
    return lines[0]


# ----------------------------------------------------------------------------- calibration files


@pytest.fixture
def calib(tmp_path):
    """A valid ``calib.npz`` (a straight virtual rig's ideal calibration, 3^3 colour samples) and a capture."""
    rig = straight_rig(HW, delta_psf())
    path = tmp_path / "calib.npz"
    rig.ideal_calibration(levels=3).save(path)
    capture = tmp_path / "capture.png"
    write_rgb_png(capture, np.full(HW + (3,), 0.5, np.float32))
    return path, capture


def _edited(path, target, **changes):
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in changes.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = np.asarray(value)
    np.savez(target, **arrays)
    return target


def test_a_saved_calibration_round_trips_through_the_check(calib):
    path, _ = calib
    loaded = ProCamsCalibration.load(path)
    assert loaded.projector_hw == HW and loaded.color.neighbours == 6


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.5, 0.99])
def test_truncated_or_empty_calibration_files_are_refused_in_one_line(calib, tmp_path, capsys, fraction):
    path, capture = calib
    damaged = tmp_path / "c.npz"
    data = path.read_bytes()
    damaged.write_bytes(data[: int(fraction * len(data))])
    line = run_error(
        capsys, ["procams", "rectify", str(capture), "--calib", str(damaged), "--out", str(tmp_path / "r.png")]
    )
    assert "c.npz" in line and ("truncated or damaged" in line or "not a NumPy" in line)
    assert not (tmp_path / "r.png").exists()


@pytest.mark.parametrize(
    "changes, expected",
    [
        ({"mixing_matrix": np.ones((3, 3))}, "singular colour-mixing matrix"),
        ({"mixing_matrix": np.eye(2)}, "'mixing_matrix' of shape"),
        ({"map_x": np.zeros((5, 5))}, "'map_x' of shape"),
        ({"black_image": np.zeros((16, 20))}, "'black_image' of shape"),
        ({"color_inputs": np.zeros((0, 3)), "color_outputs": np.zeros((0, 3))}, "colour tables"),
        ({"neighbours": 0}, "neighbours=0"),
        ({"neighbours": 1e9}, "neighbours=1000000000"),
        ({"neighbours": 2.5}, "neighbours=2.5"),
        ({"projector_hw": [100000, 100000]}, "each side must be 1..32768"),
        ({"projector_hw": [-16, 20]}, "each side must be 1..32768"),
        ({"camera_hw": [16]}, "not two whole numbers"),
        ({"map_x": np.full(HW, 25.0)}, r"'map_x' outside the 16x20 \(height x width\) camera frame"),
        ({"map_y": np.full(HW, -1.0)}, "'map_y' outside"),
        ({"black_level": [np.nan, 0, 0]}, "NaN or infinite values in 'black_level'"),
        ({"dots_cam": np.zeros((3, 2))}, "dot lists"),
        ({"color_inputs": np.full((27, 3), 2.0)}, "inputs outside \\[0, 1\\]"),
        ({"homography": None}, "lacks homography"),
        ({"format": "something else"}, "is not a calibration file"),
    ],
)
def test_every_field_of_a_calibration_is_checked_in_one_line(calib, tmp_path, changes, expected):
    path, _ = calib
    bad = _edited(path, tmp_path / "bad.npz", **changes)
    with pytest.raises(EdofprojError, match=expected) as refused:
        ProCamsCalibration.load(bad)
    assert "\n" not in str(refused.value) and "bad.npz" in str(refused.value)


def test_compensate_refuses_a_damaged_calibration_in_one_line(calib, tmp_path, capsys):
    path, capture = calib
    bad = _edited(path, tmp_path / "bad.npz", neighbours=1e9)
    line = run_error(
        capsys,
        [
            "compensate",
            "builtin:cpu-doe-net",
            "--image",
            str(capture),
            "--capture",
            str(capture),
            "--calib",
            str(bad),
            "--out",
            str(tmp_path / "o.png"),
        ],
    )
    assert "neighbours=1000000000" in line


# ----------------------------------------------------------------------------- pattern manifests


@pytest.fixture
def pattern_dir(tmp_path):
    manifest, images = build_pattern_set(
        PatternSpec(width=20, height=16, dot_grid=(2, 2), color_levels=2, bernoulli_count=2)
    )
    folder = tmp_path / "patterns"
    for name, image in images.items():
        write_rgb_png(folder / name, image)
    (folder / MANIFEST_NAME).write_text(manifest_json_text(manifest))
    return folder


def _edit_manifest(folder, edit):
    path = folder / MANIFEST_NAME
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("name", ["../x/escaped.png", "/tmp/escaped.png", "sub/x.png", ".hidden.png", "", ".."])
def test_manifest_file_names_stay_inside_the_pattern_folder(pattern_dir, name):
    _edit_manifest(pattern_dir, lambda d: d["files"][0].update(file=name))
    with pytest.raises(EdofprojError, match="not a bare file name inside the folder"):
        PatternManifest.load(pattern_dir)


@pytest.mark.parametrize(
    "edit, expected",
    [
        (lambda d: d.update(width=100000), "is not 16..32768"),
        (lambda d: d.update(width=1.5), "'width' 1.5 is not a whole number"),
        (lambda d: d["files"].append(dict(d["files"][0])), "listed twice"),
        (lambda d: d["files"][3].update(color=[2, 0, 0]), "outside \\[0, 1\\]"),
        (lambda d: d.update(files=[]), "no pattern files"),
        (lambda d: d["files"][2].update(dots=[[-5, 0]] * 4), "dots outside"),
    ],
)
def test_every_manifest_field_is_checked(pattern_dir, edit, expected):
    _edit_manifest(pattern_dir, edit)
    with pytest.raises(EdofprojError, match=expected):
        PatternManifest.load(pattern_dir)


def test_a_manifest_that_is_a_list_or_not_utf8_is_refused(pattern_dir):
    (pattern_dir / MANIFEST_NAME).write_text("[1, 2]")
    with pytest.raises(EdofprojError, match="not a pattern manifest"):
        PatternManifest.load(pattern_dir)
    (pattern_dir / MANIFEST_NAME).write_bytes(b"\xff\xfe{")
    with pytest.raises(EdofprojError, match="not UTF-8"):
        PatternManifest.load(pattern_dir)


def test_calibrating_a_huge_manifest_is_refused_before_anything_is_read(pattern_dir, monkeypatch):
    manifest = PatternManifest.load(pattern_dir)
    manifest.width = manifest.height = 31623  # 1e9 pixels
    monkeypatch.setenv("EDOFPROJ_MEMORY_BYTES", str(16 << 30))
    with pytest.raises(EdofprojError, match=r"calibrating a 31623x31623 \(height x width\) projector .* needs about"):
        calibrate(manifest, {})


# ----------------------------------------------------------------------------- capture sessions


def _capture(pattern_dir, out, **kwargs):
    display = MemoryDisplay()
    return capture_patterns(pattern_dir, out, display, VirtualCamera(straight_rig(HW, delta_psf()), display), **kwargs)


def test_a_session_refuses_patterns_regenerated_in_place(pattern_dir, tmp_path):
    out = tmp_path / "captures"
    _capture(pattern_dir, out, stop_after=2)
    info = json.loads((out / CAPTURE_INFO_JSON).read_text())
    assert len(info["patterns_sha256"]) == 64
    manifest, images = build_pattern_set(
        PatternSpec(width=20, height=16, dot_grid=(2, 2), color_levels=2, bernoulli_count=2, seed=7)
    )
    for name, image in images.items():  # as 'procams patterns --seed 7 --overwrite' would
        write_rgb_png(pattern_dir / name, image)
    with pytest.raises(EdofprojError, match="patterns of .* have changed"):
        _capture(pattern_dir, out)
    assert json.loads((out / CAPTURE_INFO_JSON).read_text()) == info  # nothing rewritten


def test_a_session_without_a_patterns_hash_is_not_resumed(pattern_dir, tmp_path):
    out = tmp_path / "captures"
    _capture(pattern_dir, out, stop_after=1)
    info = json.loads((out / CAPTURE_INFO_JSON).read_text())
    del info["patterns_sha256"]
    (out / CAPTURE_INFO_JSON).write_text(json.dumps(info))
    with pytest.raises(EdofprojError, match="does not record its patterns' content"):
        _capture(pattern_dir, out)


def test_damaged_captures_are_captured_again_not_counted(pattern_dir, tmp_path):
    out = tmp_path / "captures"
    _capture(pattern_dir, out, stop_after=3)
    first = PatternManifest.load(pattern_dir).entries[1].file
    good = (out / first).read_bytes()
    (out / first).write_bytes(good[:50])  # truncated
    with pytest.warns(RecoveryWarning, match="1 capture\\(s\\) .* did not decode"):
        result = _capture(pattern_dir, out)
    assert result.skipped == 2 and result.captured == result.total - 2
    assert (out / first).read_bytes() == good  # the same noise-free capture again


def test_a_captures_json_that_is_a_list_is_refused(pattern_dir, tmp_path):
    out = tmp_path / "captures"
    out.mkdir()
    (out / CAPTURE_INFO_JSON).write_text("[1, 2]")
    with pytest.raises(EdofprojError, match="not a capture session's record"):
        _capture(pattern_dir, out)


def test_a_manifest_cannot_make_capture_write_outside_its_session(pattern_dir, tmp_path):
    outside = tmp_path / "x" / "escaped.png"
    _edit_manifest(pattern_dir, lambda d: d["files"][0].update(file="../x/escaped.png"))
    with pytest.raises(EdofprojError, match="not a bare file name"):
        _capture(pattern_dir, tmp_path / "captures")
    assert not outside.parent.exists() and not (tmp_path / "captures").exists()


# ----------------------------------------------------------------------------- scene files


@pytest.mark.parametrize("name", ["../cube.stl", "/tmp/cube.stl"])
def test_scene_mesh_files_stay_inside_the_scene_folder(tmp_path, name):
    from edofproj.config import load_config
    from edofproj.optics.geometry import ProjectorGeometry
    from edofproj.scenes.loader import load_scene

    folder = tmp_path / "scene"
    folder.mkdir()
    (folder / "s.yaml").write_text(f"meshes:\n  - file: {name}\n")
    with pytest.raises(EdofprojError, match="inside it \\(no absolute path, no '..'\\)"):
        load_scene(str(folder / "s.yaml"), ProjectorGeometry.from_config(load_config("cpu").optics))


def test_copying_the_pattern_fixture_keeps_it_valid(pattern_dir, tmp_path):
    shutil.copytree(pattern_dir, tmp_path / "copy")
    assert len(PatternManifest.load(tmp_path / "copy").entries) == 2 + 6 + 8


def test_a_tagged_archive_of_another_format_or_missing_a_key_is_one_line(tmp_path):
    """``fileio.read_tagged_arrays`` (PSF maps, correspondence maps): the tag and the keys are checked."""
    from edofproj.fileio import read_tagged_arrays
    from edofproj.procams.psf_map import PSFMap
    from edofproj.procams.structured_light import CorrespondenceMap

    np.savez(tmp_path / "other.npz", format=np.array("something-else"), xs=np.zeros(2))
    for load, what in ((PSFMap.load, "is not a PSF map"), (CorrespondenceMap.load, "is not a correspondence map")):
        with pytest.raises(EdofprojError, match=what):
            load(tmp_path / "other.npz")
    np.savez(tmp_path / "partial.npz", format=np.array("fmt"), a=np.zeros(1))
    with pytest.raises(EdofprojError, match="lacks b, c"):
        read_tagged_arrays(tmp_path / "partial.npz", "thing", "fmt", ("a", "b", "c"), "make one")
    assert set(read_tagged_arrays(tmp_path / "partial.npz", "thing", "fmt", ("a",), "make one")) == {"format", "a"}
