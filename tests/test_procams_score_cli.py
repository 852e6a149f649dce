"""``edofproj procams score`` through files: a rig whose dots are single lit camera pixels (their kernels
are then deltas: the blur is the identity inside the dots' cells), scores in closed form, and one-line
errors on bad input."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edofproj.cli import main
from edofproj.procams.protocol_score import matlab_ssim
from edofproj.procams.psf_map import PSFMap, save_psf_maps
from edofproj.procams.structured_light import CorrespondenceMap
from virtual_rigs import write_dots_lab

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
    write_dots_lab(root, (H, W), S)
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
    argv += ["--crop", ",".join(map(str, crop)), "--optimum", "3"]
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
        # under the identity, the least-squares optimum is the original itself
        assert "least-squares optimum (3 it." in lines[t + 4] and lines[t + 4].split()[-3:] == [
            "1.0000",
            "inf",
            "0.000",
        ]


def constant_map(sigma_x: float, sigma_y: float, channel: str) -> PSFMap:
    xs, ys = np.array([0.0, 30.0, 59.0]), np.array([0.0, 47.0])
    cov = np.zeros((2, 3, 2, 2))
    cov[..., 0, 0], cov[..., 1, 1] = sigma_x**2, sigma_y**2
    return PSFMap(xs, ys, cov, np.zeros(2), np.ones((2, 3), bool), (H, W), channel)


def gaussian(sigma_x: float, sigma_y: float) -> np.ndarray:
    """The sampled Gaussian out to 4 sigma, sum 1, written out here."""
    r = int(math.ceil(4 * max(sigma_x, sigma_y)))
    y, x = np.mgrid[-r : r + 1, -r : r + 1].astype(np.float64)
    k = np.exp(-0.5 * (x**2 / sigma_x**2 + y**2 / sigma_y**2))
    return k / k.sum()


def test_psf_map_blur_scores_as_a_plain_convolution_per_colour(rig, capsys):
    """A map constant across the image blurs by one Gaussian per colour (zero outside the image): the
    scores equal those of scipy's convolution, rounded to 8 bits as MATLAB's uint8() rounds."""
    from scipy import ndimage

    root, original = rig
    widths = {"red": (0.6, 1.0), "green": (0.9, 1.6), "blue": (1.3, 2.4)}
    path = root / "psf_rgb.npz"
    save_psf_maps(path, [constant_map(*w, c) for c, w in widths.items()])
    comp = cv2.imread(str(root / "comp.png"))[..., ::-1].astype(np.float64)
    crop = (4, 40, 6, 55)
    argv = ["procams", "score", "--psf-map", str(path), "--image", str(root / "original.png")]
    argv += ["--compensation", str(root / "comp.png"), "--crop", ",".join(map(str, crop))]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "the maps of red, green, blue" in lines[1]

    def blur(image):
        planes = [ndimage.convolve(image[..., c], gaussian(*w), mode="constant") for c, w in enumerate(widths.values())]
        return np.floor(np.stack(planes, -1) + 0.5)[crop[0] : crop[1], crop[2] : crop[3]]

    ref = original.astype(np.float64)[crop[0] : crop[1], crop[2] : crop[3]]
    normal, after = blur(original.astype(np.float64)), blur(comp)
    peak = min(normal.max(), ref.max())
    for line, image in zip(lines[3:5], (normal, after)):
        mse = np.mean((image - ref) ** 2)
        ssim, psnr, rmse = (float(v) for v in line.split()[-3:])
        assert ssim == pytest.approx(matlab_ssim(image, ref)[0], abs=6e-5)
        assert psnr == pytest.approx(10 * math.log10(peak**2 / mse), abs=0.006)
        assert rmse == pytest.approx(math.sqrt(mse), abs=6e-4)


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
    assert "go with --dots" in run_error(capsys, [*base, "--psf-map", "x.npz", "--lab", str(root / "lab.json")])
    assert "needs --lab" in run_error(capsys, [*base, "--dots", "dots"])
    assert "--optimum 0 must be" in run_error(capsys, [*base, *lab_args(root), "--optimum", "0"])
    assert "four integers" in run_error(capsys, [*base, *lab_args(root), "--crop", "1,2"])
    assert "not inside" in run_error(capsys, [*base, *lab_args(root), "--crop", "0,49,0,10"])
    assert "no sequence 'dotz'" in run_error(capsys, [*base, *lab_args(root)[:3], "dotz", *lab_args(root)[4:]])
    assert "not 'dots'" in run_error(capsys, [*base, *lab_args(root)[:3], "background", *lab_args(root)[4:]])
    other = constant_map(1.0, 1.0, "mean")
    other.projector_hw = (H + 1, W)
    other.save(root / "other.npz")
    assert "60x49 projector" in run_error(capsys, [*base, "--psf-map", str(root / "other.npz")])
    small = ["procams", "score", "--image", str(root / "original.png"), "--compensation", str(root / "small.png")]
    assert "small.png' is 60x47" in run_error(capsys, [*small, *lab_args(root)])
    missing = ["procams", "score", "--image", str(root / "nothing.png"), "--compensation", str(root / "comp.png")]
    assert "does not exist" in run_error(capsys, [*missing, *lab_args(root)])
