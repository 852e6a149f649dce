"""The Gray code's stripe edges give the map to a fraction of a pixel; its held-in planes give the blur.

Synthetic captures of a board seen through a known homography (with a mild distortion), a wall
beside it, projector pixels as boxes blurred by a Gaussian, camera pixels integrating 3x3
sub-samples, an exposure that changes between frames, noise and 8-bit quantization."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.special import ndtr

from edofproj.errors import EdofprojError
from edofproj.procams.code_blur import blur_psf_map, fit_blur_width, seen_profile
from edofproj.procams.edge_map import EdgePoints, decode_gray_code_edges, fit_edge_surface
from edofproj.procams.prediction import predict_capture
from edofproj.procams.structured_light import CorrespondenceMap, decode_gray_code, gray_code_profiles

LENGTH = 256  # projector columns: 8 Gray-code planes
PROJ_HW = (48, LENGTH)
CAMERA_HW = (150, 300)
HELD_IN = 5  # stripes 8 px wide; planes 6-8 (8, 4 and 2 px) held out
BOARD_U = 60  # camera columns left of it see a wall
SIGMA_PX = 1.0  # optical blur of a projector pixel (a box), projector px


def board_x(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The projector column a camera point sees: a plane's homography row plus a mild distortion."""
    x = (0.9 * u + 0.05 * v - 50.0) / (0.0004 * u + 0.0002 * v + 1.0) + 1e-5 * (u - 150.0) ** 2
    wall = 1.1 * u + 0.3 * v - 40.0
    return np.where(u < BOARD_U - 0.5, wall, x)


def render(profiles: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Captures ``(n, Hc, Wc)`` of the planes and the true coordinate at every camera pixel's centre."""
    rng = np.random.default_rng(seed)
    Hc, Wc = CAMERA_HW
    v, u = np.mgrid[0:Hc, 0:Wc].astype(np.float64)
    offsets = (np.arange(3) - 1) / 3.0
    dark = 0.08 + 0.04 * u / Wc
    bright = 0.75 - 0.1 * ((u - Wc / 2) / Wc) ** 2
    out = []
    for i, profile in enumerate(profiles):
        seen = np.zeros(CAMERA_HW)
        for du in offsets:
            for dv in offsets:
                x = board_x(u + du, v + dv)
                base = np.floor(x).astype(np.int64)
                for d in range(-6, 7):
                    kk = base + d
                    inside = (kk >= 0) & (kk < LENGTH)
                    box = ndtr((x - kk + 0.5) / SIGMA_PX) - ndtr((x - kk - 0.5) / SIGMA_PX)
                    seen += np.where(inside, profile[np.clip(kk, 0, LENGTH - 1)] * box, 0.0) / 9.0
        gain, offset = 1.0 + 0.08 * math.sin(1.7 * i), 0.02 * math.cos(i)  # exposure drift
        frame = gain * (dark + (bright - dark) * seen) + offset + rng.normal(0, 0.004, CAMERA_HW)
        out.append(np.round(np.clip(frame, 0, 1) * 255) / 255)
    return np.stack(out), board_x(u, v)


@pytest.fixture(scope="module")
def scene():
    profiles = gray_code_profiles(LENGTH)
    captures, truth = render(profiles)
    result = decode_gray_code_edges(captures[:HELD_IN], LENGTH, PROJ_HW)
    return profiles, captures, truth, result


def test_edges_give_the_map_to_a_fraction_of_a_pixel(scene) -> None:
    _, captures, truth, result = scene
    valid = result.decoding.valid
    board = np.zeros(CAMERA_HW, dtype=bool)
    board[:, BOARD_U + 2 :] = True
    error = np.abs(result.decoding.coordinate - truth)[valid & board]
    assert valid[board].mean() > 0.8
    assert np.median(error) < 0.03 and np.percentile(error, 99) < 0.12
    # the stripes alone know the coordinate to +-4 px
    stripes = decode_gray_code(captures[:HELD_IN], LENGTH)
    coarse = np.abs(stripes.coordinate - truth)[stripes.valid & board]
    assert np.median(coarse) > 1.0
    # the wall is another surface: its edges are outliers and its pixels not valid
    wall = np.zeros(CAMERA_HW, dtype=bool)
    wall[:, : BOARD_U - 2] = True
    assert valid[wall].mean() < 0.02
    assert result.inliers[result.edges.u < BOARD_U - 2].mean() < 0.05


def test_the_held_in_planes_measure_the_blur(scene) -> None:
    _, _, _, result = scene
    # a box pixel (variance 1/12) blurred by SIGMA_PX, seen by camera pixels 0.6 projector px wide
    expected = math.sqrt(SIGMA_PX**2 + 1 / 12 + (0.6**2) / 12)
    assert abs(result.sigma_px - expected) < 0.1


def test_held_out_planes_are_predicted_with_the_edge_map_and_measured_blur(scene) -> None:
    profiles, captures, truth, result = scene
    dec = result.decoding
    corr = CorrespondenceMap(dec.coordinate, np.full(CAMERA_HW, np.nan), PROJ_HW)
    v, u = np.nonzero(corr.valid)
    fit = fit_blur_width(
        captures[:HELD_IN, v, u], profiles[:HELD_IN], corr.proj_x[v, u], dec.dark[v, u], dec.bright[v, u], PROJ_HW,
        (corr.proj_x[v, u], corr.proj_y[v, u]), cell_px=32,
    )  # fmt: skip
    psf_map = blur_psf_map(fit, "x", PROJ_HW)
    assert psf_map.sigma_x.shape == (2, len(fit.xs))  # bands along x: the map has no rows
    stripes = decode_gray_code(captures[:HELD_IN], LENGTH)
    coarse = CorrespondenceMap(np.where(corr.valid, stripes.coordinate, np.nan), corr.proj_y, PROJ_HW)
    for plane in (5, 6, 7):  # stripes 8, 4 and 2 px
        image = np.broadcast_to(profiles[plane][None, :], PROJ_HW)
        sharp = predict_capture(image, captures[plane], corr, dec.dark, dec.bright, psf_map=psf_map)
        unblurred = predict_capture(image, captures[plane], corr, dec.dark, dec.bright, psf_map=None)
        quantized = predict_capture(image, captures[plane], coarse, dec.dark, dec.bright, psf_map=psf_map)
        assert sharp.psnr_db > 35.0, plane
        assert sharp.psnr_db > quantized.psnr_db + 5.0
        if plane < 7:  # the 2-px stripes keep a quarter of their contrast: no blur and a small gain fit them too
            assert sharp.psnr_db > unblurred.psnr_db + 5.0


def test_the_search_runs_along_whichever_camera_axis_crosses_the_stripes(scene) -> None:
    _, captures, _, result = scene
    turned = decode_gray_code_edges(captures[:HELD_IN].transpose(0, 2, 1), LENGTH, PROJ_HW)
    both = turned.decoding.valid & result.decoding.valid.T
    assert both.sum() > 0.9 * result.decoding.valid.sum()
    assert np.max(np.abs(turned.decoding.coordinate - result.decoding.coordinate.T)[both]) < 1e-6


def test_seen_profile_is_the_sum_of_sampled_gaussians() -> None:
    profile = np.zeros(32)
    profile[10] = 1.0
    x = np.linspace(5.0, 15.0, 41)
    seen = seen_profile(profile, x, 1.5)
    g = np.exp(-0.5 * ((x[:, None] - np.arange(32)[None, :]) / 1.5) ** 2)
    assert np.allclose(seen, g[:, 10] / g.sum(axis=1), atol=1e-6)
    assert np.allclose(seen_profile(np.ones(32), x, 0.7), 1.0)


def test_a_surface_through_too_few_edges_is_refused() -> None:
    few = EdgePoints(np.arange(10.0), np.zeros(10), np.arange(10.0), np.zeros(10, int), np.ones(10, bool))
    with pytest.raises(EdofprojError, match="too few"):
        fit_edge_surface(few, CAMERA_HW)


def test_decode_edges_psf_map_code_and_predict_commands(tmp_path, capsys, scene) -> None:
    """A lab folder of Gray-code captures: ``decode --edges``, ``psf-map --code`` and ``predict`` of a
    held-out plane, as a lab runs them; ``--edges`` on a phase shift fails in one line (exit 2)."""
    from edofproj.cli import main
    from edofproj.procams.capture_io import write_rgb_png

    profiles, captures, _, _ = scene
    names = [f"gray_{b:02d}.png" for b in range(len(profiles))]
    for name, capture in zip(names, captures):
        write_rgb_png(tmp_path / name, np.repeat(capture[..., None], 3, axis=-1))
    manifest = {
        "format": "edofproj-lab-captures", "version": 1,
        "projector": {"height": PROJ_HW[0], "width": PROJ_HW[1]},
        "sequences": [
            {"name": "gray", "kind": "gray-code", "axis": "x", "planes": len(profiles), "files": {"list": names}},
            {"name": "phase", "kind": "phase-shift", "axis": "x", "periods": [1, 4], "steps": 4,
             "files": {"list": names}},
        ],
    }  # fmt: skip
    (tmp_path / "lab.json").write_text(json.dumps(manifest))
    held_out = tmp_path / "plane_7.png"
    write_rgb_png(held_out, np.repeat(np.broadcast_to(profiles[6][None, :], PROJ_HW)[..., None], 3, axis=-1))

    def cli(*args: str):
        capsys.readouterr()
        code = main(["procams", *args])
        out = capsys.readouterr()
        return code, out.out, out.err

    lab = ("--lab", str(tmp_path / "lab.json"))
    code, out, err = cli(
        "decode", *lab, "--x", "gray", "--planes", str(HELD_IN), "--edges", "--out", str(tmp_path / "m.npz")
    )
    assert code == 0, err
    assert "stripe edges" in out and "blur along x" in out
    code, out, err = cli("psf-map", *lab, "--code", "gray", "--planes", str(HELD_IN), "--map", str(tmp_path / "m.npz"),
                         "--out", str(tmp_path / "p.npz"))  # fmt: skip
    assert code == 0, err
    scores = []
    for blur in (("--psf-map", str(tmp_path / "p.npz")), ()):
        code, out, err = cli("predict", "--map", str(tmp_path / "m.npz"), *blur, "--image", str(held_out),
                             "--capture", str(tmp_path / names[6]))  # fmt: skip
        assert code == 0, err
        scores.append(float(out.split("PSNR ")[1].split(" dB")[0]))
    assert scores[0] > 35.0 and scores[0] > scores[1] + 5.0
    code, _, err = cli("decode", *lab, "--x", "phase", "--edges", "--out", str(tmp_path / "bad.npz"))
    assert code == 2 and "not a Gray code" in err and "Traceback" not in err
    assert not (tmp_path / "bad.npz").exists()


def test_a_moved_camera_gets_its_map_from_its_own_stripe_edges() -> None:
    """The virtual ProCams, its camera turned and shifted after a phase-decoded session: the first 4
    Gray-code planes (8-px stripes) of the new pose give its columns more closely than the old map
    carried over and anchored to the same planes."""
    from edofproj.procams.camera_motion import carry_map
    from edofproj.procams.structured_light import decode_phase_shift
    from edofproj.procams.virtual import VirtualProCams
    from test_procams_structured_light import PERIODS_X, PERIODS_Y, gray_frames, inside, make_rig, phase_frames, truth

    before = make_rig()
    hw = before.projector_hw
    angle = math.radians(1.5)
    motion = np.array([[math.cos(angle), -math.sin(angle), 6.0], [math.sin(angle), math.cos(angle), -4.0], [0, 0, 1]])
    after = VirtualProCams(projector_hw=hw, camera_hw=before.camera_hw, psf=before.psf,
                           homography=motion @ before.homography, radial_k1=0.0, gamma=1.0,
                           projector_black=0.0, noise_sigma=0.003)  # fmt: skip
    x = decode_phase_shift(phase_frames(before, "x", PERIODS_X), PERIODS_X, 4, hw[1])
    y = decode_phase_shift(phase_frames(before, "y", PERIODS_Y), PERIODS_Y, 4, hw[0])
    frames = gray_frames(after)[:4]
    coarse = decode_gray_code(frames, hw[1])
    carried, _ = carry_map(
        CorrespondenceMap.from_decodings(x, y, hw), 0.5 * (x.bright + y.bright), coarse, "x", coarse.bright
    )
    edges = decode_gray_code_edges(frames, hw[1], hw)
    tx, ty = truth(after)
    ok = edges.decoding.valid & inside(tx, ty) & carried.valid
    assert ok.sum() > 0.7 * inside(tx, ty).sum()
    from_edges = np.median(np.abs(edges.decoding.coordinate - tx)[ok])
    from_carry = np.median(np.abs(carried.proj_x - tx)[ok])
    assert from_edges < 0.1 and from_edges < 0.5 * from_carry
