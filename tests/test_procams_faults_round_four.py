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
    phase_shift_profiles,
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
    projection each frame has its own gain and a stray light that grows with the lit area (up to
    0.2), which the unlit columns do not see."""
    out = np.empty((len(images), PROJ_HW[0], UNLIT + PROJ_HW[1]))
    for i, image in enumerate(images):
        out[i, :, :UNLIT] = 0.06
        out[i, :, UNLIT:] = (0.8 + 0.3 * i / len(images)) * (0.06 + 0.6 * image) + 0.2 * image.mean()
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
