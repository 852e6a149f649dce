"""``edofproj procams score`` through files: a rig whose dots are single lit camera pixels (their kernels
are then deltas: the blur is the identity inside the dots' cells), scores in closed form, and one-line
errors on bad input."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from edofproj.cli import main
from edofproj.procams.structured_light import CorrespondenceMap

H, W, S = 48, 60, 12


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    root = tmp_path_factory.mktemp("score")
    # camera = projector, seen through a map with the offset o = (1, 1) of 1-based phase origins
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    inside = (u + 1 <= W - 1) & (v + 1 <= H - 1)  # the last row and column see beyond the projector
    proj_x, proj_y = np.where(inside, u + 1.0, np.nan), np.where(inside, v + 1.0, np.nan)
    CorrespondenceMap(proj_x=proj_x, proj_y=proj_y, projector_hw=(H, W)).save(root / "map.npz")
    dots = np.zeros((H, W, 3), np.uint8)
    dots[::S, ::S] = 230
    background = np.full((H, W, 3), 30, np.uint8)
    cv2.imwrite(str(root / "dots.png"), np.maximum(dots, background))
    cv2.imwrite(str(root / "background.png"), background)
    manifest = {
        "format": "edofproj-lab-captures",
        "version": 1,
        "projector": {"height": H, "width": W},
        "sequences": [
            {"name": "dots", "kind": "dots", "spacing_px": [S, S], "files": {"list": ["dots.png"]}},
            {"name": "background", "kind": "black", "files": {"list": ["background.png"]}},
        ],
    }
    (root / "lab.json").write_text(json.dumps(manifest))
    rng = np.random.default_rng(0)
    original = rng.integers(0, 220, (H, W, 3)).astype(np.uint8)
    comp = original.copy()
    comp[20:23, 30:34, 2] += 6  # 12 values off by 6
    cv2.imwrite(str(root / "original.png"), original[..., ::-1])
    cv2.imwrite(str(root / "comp.png"), comp[..., ::-1])
    cv2.imwrite(str(root / "small.png"), original[:-1, ..., ::-1])
    return root, original


def lab_args(root):
    return ["--lab", str(root / "lab.json"), "--dots", "dots", "--map", str(root / "map.npz"), "--offset-px", "1", "1"]


def test_delta_kernels_score_the_closed_form(rig, capsys):
    root, original = rig
    crop = (5, 36, 3, 48)  # inside the complete cells: rows < 36, columns < 48
    argv = ["procams", "score", *lab_args(root), "--background", "background"]
    argv += ["--image", str(root / "original.png"), "--compensation", str(root / "comp.png")]
    argv += ["--crop", ",".join(map(str, crop))]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "crop rows 5..35, columns 3..47 (45x31 px, 3 colours)"
    tables = [i for i, line in enumerate(lines) if line.startswith("blur: ")]
    assert len(tables) == 2 and "red channel's" in lines[tables[0]] and "each colour" in lines[tables[1]]
    mse = 12 * 36.0 / (31 * 45 * 3)
    peak = float(original[5:36, 3:48].max())
    for t in tables:
        normal, comp = lines[t + 2].split(), lines[t + 3].split()
        assert normal[-3:] == ["1.0000", "inf", "0.000"]
        assert comp[0] == "comp.png"
        assert float(comp[-2]) == pytest.approx(10 * math.log10(peak**2 / mse), abs=0.006)
        assert float(comp[-1]) == pytest.approx(math.sqrt(mse), abs=6e-4)


def run_error(capsys, argv):
    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("edofproj: error: ")
    return lines[0]


def test_one_line_errors(rig, capsys):
    root, _ = rig
    images = ["--image", str(root / "original.png"), "--compensation", str(root / "comp.png")]
    base = ["procams", "score", *images]
    assert "needs --lab" in run_error(capsys, [*base, "--dots", "dots"])
    assert "four integers" in run_error(capsys, [*base, *lab_args(root), "--crop", "1,2"])
    assert "not inside" in run_error(capsys, [*base, *lab_args(root), "--crop", "0,49,0,10"])
    assert "no sequence 'dotz'" in run_error(capsys, [*base, *lab_args(root)[:3], "dotz", *lab_args(root)[4:]])
    assert "not 'dots'" in run_error(capsys, [*base, *lab_args(root)[:3], "background", *lab_args(root)[4:]])
    small = ["procams", "score", "--image", str(root / "original.png"), "--compensation", str(root / "small.png")]
    assert "small.png' is 60x47" in run_error(capsys, [*small, *lab_args(root)])
    missing = ["procams", "score", "--image", str(root / "nothing.png"), "--compensation", str(root / "comp.png")]
    assert "does not exist" in run_error(capsys, [*missing, *lab_args(root)])
