"""Issue 60 (round four) on the procams lab path: each case end to end through the command line, on
synthetic captures, failing before its fix: decoding gated in the captures' own units and on
coherent neighbours, axes checked, lab manifests checked, refusals with one line that says what to do."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.structured_light import (
    CorrespondenceMap,
    gray_code_profiles,
    profiles_to_images,
)

PROJ_HW = (32, 256)  # 8 Gray-code planes along x, 5 along y


def cli(capsys, *args) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def write_lab(folder, sequences, hw=PROJ_HW) -> None:
    data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": hw[0], "width": hw[1]},
            "sequences": sequences}  # fmt: skip
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")


def write_frames(folder, prefix: str, frames) -> list[str]:
    names = []
    for i, frame in enumerate(frames):
        names.append(f"{prefix}_{i:02d}.png")
        write_rgb_png(folder / names[-1], np.repeat(np.clip(frame, 0, 1)[..., None], 3, -1))
    return names


UNLIT = 144  # camera columns left of the projection


def camera_view(images: np.ndarray, rng) -> np.ndarray:
    """``(n, 32, UNLIT + 256)`` captures: the projector images seen one to one right of ``UNLIT``
    columns the projector does not reach (a constant dark level and camera noise); on the
    projection each frame has its own gain and its own dark level (an exposure that changes, stray
    light from the projector: 0 to 0.25 above the unlit part's, as on a real rig), which the unlit
    columns do not see."""
    offsets = np.random.default_rng(7).uniform(0.0, 0.25, len(images))
    out = np.empty((len(images), PROJ_HW[0], UNLIT + PROJ_HW[1]))
    for i, image in enumerate(images):
        out[i, :, :UNLIT] = 0.06
        out[i, :, UNLIT:] = 0.06 + offsets[i] + (0.8 + 0.3 * i / len(images)) * 0.6 * image
        out[i] += 0.004 * rng.standard_normal(out[i].shape)
    return out


# ------------------------------------------------------------------ item 3: unlit pixels and noise
def test_gray_code_leaves_the_unlit_pixels_invalid(tmp_path, capsys) -> None:
    """40 % of the camera sees no projector light: its pixels are not valid (they were 100 % valid,
    decoded to one column); the lit part decodes to its columns."""
    rng = np.random.default_rng(0)
    planes = profiles_to_images(gray_code_profiles(PROJ_HW[1]), PROJ_HW, "x")
    names = write_frames(tmp_path, "gray", camera_view(planes, rng))
    write_lab(tmp_path, [{"name": "gray", "kind": "gray-code", "axis": "x", "files": {"list": names}}])
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "gray",
                         "--out", tmp_path / "map.npz")  # fmt: skip
    assert code == 0, err
    corr = CorrespondenceMap.load(tmp_path / "map.npz")
    assert not corr.valid[:, :UNLIT].any()
    lit = corr.valid[:, UNLIT:]
    assert lit.mean() > 0.95
    columns = np.broadcast_to(np.arange(PROJ_HW[1], dtype=float), lit.shape)
    assert np.array_equal(corr.proj_x[:, UNLIT:][lit], columns[lit])


@pytest.mark.parametrize("kind", ["gray-code", "phase-shift"])
def test_pure_noise_does_not_decode(tmp_path, capsys, kind) -> None:
    """Captures of pure noise (uniform, independent per frame and pixel) are refused in one line;
    they decoded 100 % (Gray code) and about half (phase shift) valid."""
    rng = np.random.default_rng(1)
    count = 8 if kind == "gray-code" else 3 * 4
    names = write_frames(tmp_path, "noise", rng.uniform(0.05, 0.95, (count, 64, 256)))
    sequence = {"name": "s", "kind": kind, "axis": "x", "files": {"list": names}}
    sequence |= {"planes": 8} if kind == "gray-code" else {"periods": [1, 4, 16], "steps": 4}
    write_lab(tmp_path, [sequence])
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "s",
                         "--out", tmp_path / "map.npz")  # fmt: skip
    assert code == 2 and "do not show the sequence's pattern" in err and "Traceback" not in err
    assert not (tmp_path / "map.npz").exists()


# ------------------------------------------------------------------ item 8: all black, all white
@pytest.mark.parametrize("level", [0.0, 1.0, 0.4])
@pytest.mark.parametrize("kind", ["gray-code", "phase-shift"])
def test_captures_without_a_pattern_are_refused(tmp_path, capsys, kind, level) -> None:
    """All-black, all-white or uniformly grey captures: refused, not a 0 %-valid map with exit 0."""
    count = 8 if kind == "gray-code" else 2 * 4
    names = write_frames(tmp_path, "flat", np.full((count, 32, 256), level))
    sequence = {"name": "s", "kind": kind, "axis": "x", "files": {"list": names}}
    sequence |= {"planes": 8} if kind == "gray-code" else {"periods": [1, 4], "steps": 4}
    write_lab(tmp_path, [sequence])
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "s",
                         "--out", tmp_path / "map.npz")  # fmt: skip
    assert code == 2 and "show no pattern" in err and "projector off" in err
    assert not (tmp_path / "map.npz").exists()


# ------------------------------------------------------------------ item 4: axes
def ideal_lab(folder, hw=(48, 64)) -> None:
    """``structured_light_set``'s patterns, captured by an identity camera between 0.1 and 0.9."""
    from edofproj.procams.lab_manifest import structured_light_set

    lab, images = structured_light_set(hw, steps=4, dot_spacing_px=8)
    for name, image in images.items():
        write_rgb_png(folder / name, np.repeat((0.1 + 0.8 * image)[..., None], 3, -1))
    (folder / "lab.json").write_text(json.dumps(lab.to_json()), encoding="utf-8")


@pytest.mark.parametrize(
    ("x", "y", "message"),
    [
        ("phase_y", None, "declares 'phase_y' on axis 'y'"),
        ("phase_y", "phase_x", "swapped?"),
        ("phase_x", "phase_x", "both name 'phase_x'"),
        (None, "gray_x", "give it as --x"),
    ],
)
def test_decode_refuses_a_sequence_on_the_wrong_axis(tmp_path, capsys, x, y, message) -> None:
    ideal_lab(tmp_path)
    args = ["procams", "decode", "--lab", tmp_path / "lab.json", "--out", tmp_path / "map.npz"]
    args += ["--x", x] if x else []
    args += ["--y", y] if y else []
    code, out, err = cli(capsys, *args)
    assert code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "map.npz").exists()
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "phase_x", "--y",
                         "phase_y", "--out", tmp_path / "map.npz")  # fmt: skip
    assert code == 0, err


# ------------------------------------------------------------------ item 6, 10, 12: lab manifests
def manifest_with(folder, sequence: dict, **top) -> None:
    for name in ("a.png", "b.png", "c.png", "d.png"):
        write_rgb_png(folder / name, np.zeros((4, 4, 3)))
    data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": 40, "width": 48},
            "sequences": [sequence]} | top  # fmt: skip
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")


GRAY = {"name": "g", "kind": "gray-code", "axis": "x", "planes": 2, "files": {"list": ["a.png", "b.png"]}}


@pytest.mark.parametrize(
    ("sequence", "top", "message"),
    [
        (GRAY | {"files": {"list": ["a.png", "a.png"]}}, {}, "a.png more than once"),
        (GRAY | {"planes": 7.5}, {}, "'planes' must be a whole number, got 7.5"),
        (GRAY, {"version": 2}, "version 2 is not one this edofproj reads"),
        (
            {"name": "p", "kind": "phase-shift", "axis": "x", "periods": [1, float("nan")], "steps": 2,
             "files": {"list": ["a.png", "b.png", "c.png", "d.png"]}},
            {},
            "a period count must be a whole number, got nan",
        ),
        (
            {"name": "d", "kind": "dots", "spacing_px": [12, 12], "origin_px": [50, 0], "files": {"list": ["a.png"]}},
            {},
            "outside the 48x40 projector",
        ),
    ],
)  # fmt: skip
def test_a_lab_manifest_that_breaks_its_format_is_refused(tmp_path, capsys, sequence, top, message) -> None:
    manifest_with(tmp_path, sequence, **top)
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", sequence["name"],
                         "--out", tmp_path / "map.npz")  # fmt: skip
    assert code == 2 and message in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1


def test_a_link_out_of_the_lab_folder_is_refused(tmp_path, capsys) -> None:
    lab, outside = tmp_path / "lab", tmp_path / "elsewhere"
    lab.mkdir(), outside.mkdir()
    manifest_with(lab, GRAY)
    write_rgb_png(outside / "secret.png", np.zeros((4, 4, 3)))
    (lab / "b.png").unlink()
    (lab / "b.png").symlink_to(outside / "secret.png")
    code, out, err = cli(
        capsys, "procams", "decode", "--lab", lab / "lab.json", "--x", "g", "--out", tmp_path / "m.npz"
    )
    assert code == 2 and "leads outside the manifest's folder" in err
    (lab / "b.png").unlink()
    (lab / "sub").symlink_to(outside, target_is_directory=True)  # a linked folder, globbed
    manifest_with(lab, GRAY | {"files": {"folder": "sub", "glob": "*.png"}, "planes": 1})
    code, out, err = cli(
        capsys, "procams", "decode", "--lab", lab / "lab.json", "--x", "g", "--out", tmp_path / "m.npz"
    )
    assert code == 2 and "leads outside the manifest's folder" in err


def test_a_deeply_nested_manifest_is_one_line(tmp_path, capsys) -> None:
    (tmp_path / "lab.json").write_text("[" * 100000 + "]" * 100000, encoding="utf-8")
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "g",
                         "--out", tmp_path / "m.npz")  # fmt: skip
    assert code == 2 and "nested too deeply" in err and "Traceback" not in err


def test_a_manifest_that_is_a_folder_or_a_fifo_says_so(tmp_path, capsys) -> None:
    import os

    (tmp_path / "lab.json").mkdir()
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "lab.json", "--x", "g",
                         "--out", tmp_path / "m.npz")  # fmt: skip
    assert code == 2 and "is a folder" in err
    os.mkfifo(tmp_path / "fifo.json")  # reading it would block: refused from its type
    code, out, err = cli(capsys, "procams", "decode", "--lab", tmp_path / "fifo.json", "--x", "g",
                         "--out", tmp_path / "m.npz")  # fmt: skip
    assert code == 2 and "not a regular file" in err


# ------------------------------------------------------------------ items 8, 12: predict's inputs
def predict_inputs(folder) -> list:
    """A map (identity camera, 48x64 projector), an image, its capture and black and white captures."""
    from edofproj.procams.structured_light import AxisDecoding

    H, W = 48, 64
    v, u = np.mgrid[0:H, 0:W].astype(float)
    ones = np.ones((H, W), bool)
    x = AxisDecoding(u, ones, np.full((H, W), 0.1), np.full((H, W), 0.9))
    y = AxisDecoding(v, ones, np.full((H, W), 0.1), np.full((H, W), 0.9))
    CorrespondenceMap.from_decodings(x, y, (H, W)).save(
        folder / "map.npz", dark=np.full((H, W), 0.1, np.float32), bright=np.full((H, W), 0.9, np.float32)
    )
    image = profiles_to_images(gray_code_profiles(W), (H, W), "x")[3]
    for name, values in (("image", image), ("capture", 0.1 + 0.8 * image), ("black", np.full((H, W), 0.1)),
                         ("white", np.full((H, W), 0.9))):  # fmt: skip
        write_rgb_png(folder / f"{name}.png", np.repeat(values[..., None], 3, -1))
    return ["procams", "predict", "--map", folder / "map.npz", "--image", folder / "image.png",
            "--capture", folder / "capture.png"]  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--offset-px", "1e30", "0"], "moves every camera pixel off the 64x48 projector"),
        (["--offset-px", "nan", "0"], "is not two finite numbers"),
        (["--black", "{white}", "--white", "{black}"], "swapped?"),
    ],
)
def test_predict_refuses_what_it_cannot_use(tmp_path, capsys, extra, message) -> None:
    args = predict_inputs(tmp_path)
    extra = [e.format(white=tmp_path / "white.png", black=tmp_path / "black.png") for e in extra]
    code, out, err = cli(capsys, *args, *extra)
    assert code == 2 and message in err and "Traceback" not in err, err
    code, out, err = cli(capsys, *args, "--black", tmp_path / "black.png", "--white", tmp_path / "white.png")
    assert code == 0 and float(out.split("PSNR ")[1].split(" dB")[0]) > 40.0, err
