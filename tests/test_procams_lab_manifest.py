"""A lab's own capture folder read through a lab manifest, and the structured-light commands end to end."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.lab_manifest import (
    LAB_FORMAT,
    LabManifest,
    decode_sequence,
    phase_frames_in_profile_order,
    structured_light_set,
)
from edofproj.procams.structured_light import phase_shift_profiles, profiles_to_images


def write_manifest(folder, sequences, hw=(40, 48)) -> None:
    data = {"format": LAB_FORMAT, "version": 1, "projector": {"height": hw[0], "width": hw[1]}, "sequences": sequences}
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")


def test_a_folder_of_time_stamped_captures_is_read_in_name_order(tmp_path) -> None:
    # another program's names: time stamps; the captures are the ideal patterns seen by an identity camera
    images = profiles_to_images(0.1 + 0.8 * phase_shift_profiles(48, [1, 4], 3), (40, 48), "x")
    (tmp_path / "RE1").mkdir()
    for i, image in enumerate(images):
        write_rgb_png(tmp_path / "RE1" / f"cam-2020-04-27-1218{i:02d}.bmp.png", np.repeat(image[..., None], 3, -1))
    sequence = {"name": "columns", "kind": "phase-shift", "axis": "x", "periods": [1, 4], "steps": 3,
                "files": {"folder": "RE1", "glob": "*.png"}}  # fmt: skip
    write_manifest(tmp_path, [sequence])
    lab = LabManifest.load(tmp_path / "lab.json")
    assert lab.sequence("columns").files[0] == "RE1/cam-2020-04-27-121800.bmp.png"
    decoded = decode_sequence(lab, "columns")
    assert np.allclose(decoded.coordinate[0], np.arange(48), atol=0.02)


def test_step_major_order_is_put_in_profile_order(tmp_path) -> None:
    names = [f"f{f}_k{k}.png" for k in range(3) for f in (1, 4)]  # step-major: k outer
    for n in names:
        write_rgb_png(tmp_path / n, np.zeros((4, 4, 3)))
    write_manifest(tmp_path, [{"name": "c", "kind": "phase-shift", "axis": "x", "periods": [1, 4], "steps": 3,
                               "order": "step-major", "files": {"list": names}}])  # fmt: skip
    seq = LabManifest.load(tmp_path / "lab.json").sequence("c")
    assert phase_frames_in_profile_order(seq) == [f"f{f}_k{k}.png" for f in (1, 4) for k in range(3)]


@pytest.mark.parametrize(
    ("sequence", "message"),
    [
        ({"name": "g", "kind": "gray-code", "axis": "x", "planes": 6, "files": {"list": ["../x.png"]}}, "inside"),
        ({"name": "g", "kind": "gray-code", "axis": "x", "planes": 6, "files": {"list": ["a.png"]}}, "needs 6 files"),
        ({"name": "g", "kind": "gray-code", "axis": "z", "planes": 2, "files": {"list": ["a", "b"]}}, "axis 'z'"),
        (
            {
                "name": "p",
                "kind": "phase-shift",
                "axis": "x",
                "periods": [4],
                "steps": 4,
                "files": {"list": ["a", "b", "c", "d"]},
            },
            "start at 1",
        ),
        ({"name": "q", "kind": "hologram", "files": {"list": ["a"]}}, "unknown kind"),
    ],
)
def test_a_bad_manifest_fails_in_one_line(tmp_path, sequence, message) -> None:
    write_manifest(tmp_path, [sequence])
    with pytest.raises(EdofprojError, match=message):
        LabManifest.load(tmp_path / "lab.json")


def test_structured_light_set_lists_every_pattern_in_capture_order() -> None:
    lab, images = structured_light_set((40, 48), steps=4, dot_spacing_px=8)
    listed = [f for s in lab.sequences for f in s.files]
    assert sorted(listed) == sorted(images) and len(set(listed)) == len(listed)
    assert lab.sequence("phase_x").periods == [1, 4] and lab.sequence("gray_y").planes == 6
    assert images["dots_8px.png"].sum() == 5 * 6


def test_patterns_decode_psf_map_and_predict_commands(tmp_path, capsys) -> None:
    """``procams patterns --structured-light``, captures of it by a virtual ProCams, then ``decode``,
    ``psf-map`` and ``predict`` as a lab runs them; a missing sequence fails in one line (exit 2)."""
    from edofproj.procams.virtual import VirtualProCams

    def cli(*args: str) -> SimpleNamespace:
        capsys.readouterr()
        code = main(["procams", *args])
        out = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)

    pat, cap = tmp_path / "pat", tmp_path / "cap"
    done = cli("patterns", "--width", "96", "--height", "72", "--out", str(pat), "--structured-light",
               "--bernoulli", "1", "--color-levels", "2", "--dots", "4x4")  # fmt: skip
    assert done.returncode == 0, done.stderr
    lab = LabManifest.load(pat / "lab.json")
    y, x = np.mgrid[-7:8, -7:8].astype(float)
    psf = np.exp(-0.5 * ((x / 1.0) ** 2 + (y / 2.0) ** 2))
    psf = np.repeat((psf / psf.sum())[None], 3, axis=0)
    rig = VirtualProCams.example((72, 96), psf, camera_scale=2.0, gamma=1.0, radial_k1=0.0,
                                 noise_sigma=0.003, projector_black=0.0)  # fmt: skip
    rng = np.random.default_rng(0)
    cap.mkdir()
    for seq in lab.sequences:
        for name in seq.files:
            write_rgb_png(cap / name, rig.capture(lab.read_rgb(name), rng))
    common = ("--lab", str(pat / "lab.json"), "--root", str(cap))
    done = cli("decode", *common, "--x", "phase_x", "--y", "phase_y", "--out", str(tmp_path / "map.npz"))
    assert done.returncode == 0, done.stderr
    assert "residual to a homography" in done.stdout
    done = cli(
        "psf-map", *common, "--dots", "dots", "--map", str(tmp_path / "map.npz"), "--out", str(tmp_path / "p.npz")
    )
    assert done.returncode == 0, done.stderr
    assert "sigma_x" in done.stdout
    finest = lab.sequence("gray_x").files[-1]
    scores = []
    for blur in (("--psf-map", str(tmp_path / "p.npz")), ()):
        done = cli("predict", "--map", str(tmp_path / "map.npz"), *blur, "--image", str(pat / finest),
                   "--capture", str(cap / finest), "--black", str(cap / "black_sl.png"),
                   "--white", str(cap / "white_sl.png"))  # fmt: skip
        assert done.returncode == 0, done.stderr
        scores.append(float(done.stdout.split("PSNR ")[1].split(" dB")[0]))
    assert scores[0] > 25.0 and scores[0] > scores[1] + 3.0  # with the PSF map, without blur
    done = cli("decode", *common, "--x", "nothing", "--out", str(tmp_path / "m2.npz"))
    assert done.returncode == 2 and "no sequence 'nothing'" in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "m2.npz").exists()
