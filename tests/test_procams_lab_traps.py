"""The traps a lab hit first on the lab path (issue 56, item 5), each on synthetic captures: one
registration for predictions with and without blur, the exposure fit of a mostly black dot capture,
decoding a subset of period counts, psf-map's progress, its figure's colour scales and its summary."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import ndimage

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.procams.prediction import blur, predict_capture, sample_at_map
from edofproj.procams.psf_map import PSFMap, covariance
from edofproj.procams.structured_light import CorrespondenceMap, gray_code_profiles, profiles_to_images

H, W = 60, 72
OFFSET = (1.0, -0.6)


def camera_points() -> tuple[np.ndarray, np.ndarray]:
    """The projector point ``(x, y)`` each camera pixel of a 2x camera sees, ``(2H, 2W)`` each."""
    v, u = np.mgrid[0 : 2 * H, 0 : 2 * W].astype(float)
    return (u - 0.5) / 2, (v - 0.5) / 2


def flat_psf_map(sigma_x: float, sigma_y: float, offset=(0.0, 0.0)) -> PSFMap:
    cov = np.broadcast_to(covariance(sigma_x, sigma_y, 0.0), (2, 2, 2, 2)).copy()
    return PSFMap(xs=np.array([0.0, W - 1.0]), ys=np.array([0.0, H - 1.0]), cov=cov,
                  offset_px=np.asarray(offset, float), fitted=np.ones((2, 2), bool), projector_hw=(H, W))  # fmt: skip


def run_cli(capsys, *args) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


# ------------------------------------------------------------------ registration with and without blur
def test_prediction_without_blur_registers_as_the_blurred_one(tmp_path, capsys) -> None:
    """A phase-decoded map shifted by ``OFFSET`` (its phase origin), a PSF map that estimated it: the
    prediction without blur (``--no-blur``) registers at the PSF map's offset as the blurred one does,
    so their scores differ by the blur alone; without any PSF map the offset is 0 0, and the output
    says which registration each used."""
    from edofproj.procams.capture_io import write_rgb_png

    tx, ty = camera_points()
    truth = CorrespondenceMap(tx, ty, (H, W))
    psf_map = flat_psf_map(1.0, 1.8, OFFSET)
    image = profiles_to_images(gray_code_profiles(W), (H, W), "x")[-3]  # 8-px stripes
    dark, bright = np.full(tx.shape, 0.05), np.full(tx.shape, 0.85)
    capture = dark + (bright - dark) * sample_at_map(blur(image, psf_map), truth)
    px, py = tx + OFFSET[0], ty + OFFSET[1]
    inside = (px >= -0.5) & (px <= W - 0.5) & (py >= -0.5) & (py <= H - 0.5)
    CorrespondenceMap(np.where(inside, px, np.nan), np.where(inside, py, np.nan), (H, W)).save(
        tmp_path / "map.npz", dark=dark.astype(np.float32), bright=bright.astype(np.float32)
    )
    psf_map.save(tmp_path / "psf.npz")
    write_rgb_png(tmp_path / "image.png", np.repeat(image[..., None], 3, -1))
    write_rgb_png(tmp_path / "capture.png", np.repeat(np.clip(capture, 0, 1)[..., None], 3, -1))
    common = ("procams", "predict", "--map", tmp_path / "map.npz", "--image", tmp_path / "image.png",
              "--capture", tmp_path / "capture.png")  # fmt: skip
    lines = {}
    for name, extra in (("blur", ("--psf-map", tmp_path / "psf.npz")),
                        ("no-blur", ("--psf-map", tmp_path / "psf.npz", "--no-blur")), ("none", ())):  # fmt: skip
        code, out, err = run_cli(capsys, *common, *extra)
        assert code == 0, err
        lines[name] = out
    psnr = {k: float(re.search(r"PSNR (\S+) dB", v).group(1)) for k, v in lines.items()}
    where = {k: re.search(r"o = \(([^)]*)\)", v).group(1) for k, v in lines.items()}
    assert where["blur"] == where["no-blur"] == "+1.00, -0.60" and where["none"] == "+0.00, +0.00"
    assert psnr["blur"] > psnr["no-blur"] + 3.0  # the blur alone
    assert psnr["no-blur"] > psnr["none"] + 1.0  # the registration alone


# ------------------------------------------------------------------ the exposure of a dot capture
def test_a_mostly_black_dot_capture_fits_a_positive_gain() -> None:
    """A dot capture, 86 % clipped to black, whose dark level is not the map's: the map's session had a
    lamp on the right half (dark level 0.35 there) that the dot capture did not. Fitted with the black
    pixels censored and the dark level's change free, the gain is the capture's (1.0) and the
    prediction good; fitted over the unclipped pixels alone with the map's dark level, the gain was
    0.009 and the prediction 34 dB."""
    tx, ty = camera_points()
    corr = CorrespondenceMap(tx, ty, (H, W))
    dots = np.zeros((H, W))
    dots[::12, ::12] = 1.0
    psf_map = flat_psf_map(1.5, 1.5)
    seen = sample_at_map(blur(dots, psf_map), corr)
    bright = np.full(tx.shape, 0.9)
    rng = np.random.default_rng(0)
    capture = np.clip(0.05 + 0.85 * seen - 0.06 + 0.004 * rng.standard_normal(seen.shape), 0, 1)
    capture = np.round(capture * 255) / 255
    assert (capture <= 0.5 / 255).mean() > 0.8
    map_dark = np.where(tx > W / 2, 0.35, 0.05)
    result = predict_capture(dots, capture, corr, map_dark, bright, psf_map=psf_map, flat_filter_px=1)
    assert 0.85 < result.gain < 1.15
    assert result.psnr_db > 45.0


# ------------------------------------------------------------------ decoding a subset of period counts
def phase_lab(folder, periods=(1, 4, 16), steps=4, garbage_from: int | None = None, axis: str = "x") -> None:
    """A lab folder of ideal phase-shift captures of a 40x48 projector seen by an identity camera;
    the frames of period counts from index ``garbage_from`` on are replaced by noise."""
    import json

    from edofproj.procams.capture_io import write_rgb_png
    from edofproj.procams.structured_light import phase_shift_profiles

    hw = (40, 48)
    length = hw[1] if axis == "x" else hw[0]
    images = profiles_to_images(0.1 + 0.8 * phase_shift_profiles(length, list(periods), steps), hw, axis)
    rng = np.random.default_rng(1)
    names = []
    for i, image in enumerate(images):
        if garbage_from is not None and i >= garbage_from * steps:
            image = rng.uniform(0.1, 0.9, image.shape)
        names.append(f"p{i:02d}.png")
        write_rgb_png(folder / names[-1], np.repeat(image[..., None], 3, -1))
    seq = {"name": "columns", "kind": "phase-shift", "axis": axis, "periods": list(periods), "steps": steps,
           "files": {"list": names}}  # fmt: skip
    data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": hw[0], "width": hw[1]},
            "sequences": [seq]}  # fmt: skip
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")


def test_decode_holds_the_finest_period_counts_out(tmp_path, capsys) -> None:
    """The finest period count's captures are noise: all three period counts decode garbage; the first
    two (``--periods 2``) decode every column to 0.05 px. ``--planes`` on a phase shift is refused."""
    phase_lab(tmp_path, garbage_from=2)
    lab = ("procams", "decode", "--lab", tmp_path / "lab.json", "--x", "columns")
    code, out, err = run_cli(capsys, *lab, "--periods", "2", "--out", tmp_path / "held.npz")
    assert code == 0, err
    held = CorrespondenceMap.load(tmp_path / "held.npz")
    assert held.valid.all() and np.allclose(held.proj_x, np.arange(48)[None, :], atol=0.05)
    code, out, err = run_cli(capsys, *lab, "--out", tmp_path / "all.npz")
    if code == 0:  # decoded, but the noise is in it
        whole = CorrespondenceMap.load(tmp_path / "all.npz")
        good = whole.valid & (np.abs(whole.proj_x - np.arange(48)[None, :]) < 0.5)
        assert good.mean() < 0.5
    code, out, err = run_cli(capsys, *lab, "--planes", "3", "--out", tmp_path / "p.npz")
    assert code == 2 and "--periods" in err and not (tmp_path / "p.npz").exists()
    code, out, err = run_cli(capsys, *lab, "--periods", "4", "--out", tmp_path / "p.npz")
    assert code == 2 and "1..3" in err


# ------------------------------------------------------------------ psf-map: progress, summary, figure
INNER_SIGMA, EDGE_SIGMA = 1.2, 3.0
EDGE_HW = (84, 96)  # dots every 12 px: 7 x 8, 26 on the edge, 18 one dot in, 12 interior


def edge_dot_lab(folder) -> None:
    """A white dot capture of an ``EDGE_HW`` projector (dots every 12 px) seen at 2 camera px per
    projector px, the dots blurred by ``INNER_SIGMA``, those at the projection's edge by ``EDGE_SIGMA``
    (their light half off the surface, their fits widened), and its map ``map.npz``."""
    import json

    from edofproj.procams.capture_io import write_rgb_png

    h, w = EDGE_HW
    v, u = np.mgrid[0 : 2 * h, 0 : 2 * w].astype(float)
    tx, ty = (u - 0.5) / 2, (v - 0.5) / 2
    light = np.zeros_like(tx)
    for y0 in range(0, h, 12):
        for x0 in range(0, w, 12):
            edge = y0 in (0, h - 12) or x0 in (0, w - 12)
            s = EDGE_SIGMA if edge else INNER_SIGMA
            light += np.exp(-0.5 * (((tx - x0) / s) ** 2 + ((ty - y0) / s) ** 2))
    write_rgb_png(folder / "dots.png", np.repeat(np.clip(0.02 + 0.8 * light, 0, 1)[..., None], 3, -1))
    seq = {"name": "dots", "kind": "dots", "spacing_px": [12, 12], "files": {"list": ["dots.png"]}}
    data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": h, "width": w},
            "sequences": [seq]}  # fmt: skip
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")
    CorrespondenceMap(tx, ty, (h, w)).save(folder / "map.npz")


def test_psf_map_shows_progress_and_summarizes_the_interior_dots(tmp_path, capsys) -> None:
    edge_dot_lab(tmp_path)
    code, out, err = run_cli(capsys, "procams", "psf-map", "--lab", tmp_path / "lab.json", "--dots", "dots",
                             "--map", tmp_path / "map.npz", "--out", tmp_path / "p.npz")  # fmt: skip
    assert code == 0, err
    # progress on stderr: each pass announced with its dot count, and its end
    assert re.search(r"psf-map \| mean: fitting dots \| 56 dots", err) and "fitting dots: done in" in err
    medians = re.search(r"median sigma_x (\S+) px, sigma_y (\S+) px", out)
    assert (
        medians
        and abs(float(medians.group(1)) - INNER_SIGMA) < 0.1
        and abs(float(medians.group(2)) - INNER_SIGMA) < 0.1
    )
    assert "over 12 interior dots (44 at the edge left out)" in out


def test_psf_map_figure_scales_by_the_interior_and_wraps_the_angle(tmp_path) -> None:
    from edofproj.procams.lab_manifest import LabManifest
    from edofproj.procams.psf_map import DotGrid, figure_panels, measure_psf_map

    edge_dot_lab(tmp_path)
    lab = LabManifest.load(tmp_path / "lab.json")
    # unsmoothed (the default median over 180 px spans this small grid and would remove the edge ring)
    psf_map, _ = measure_psf_map(lab.read_grey("dots.png"), CorrespondenceMap.load(tmp_path / "map.npz"),
                                 DotGrid.covering(EDGE_HW, (12, 12)), smooth_px=0)  # fmt: skip
    assert psf_map.sigma_x[psf_map.fitted].max() > 2.5  # the edge's widths are in the map
    sigma_x, sigma_y, angle = figure_panels(psf_map)
    assert (
        sigma_x["vmax"] < 1.5
        and sigma_x["vmin"] > 1.0
        and (sigma_x["vmin"], sigma_x["vmax"]) == (sigma_y["vmin"], sigma_y["vmax"])
    )
    import matplotlib

    assert angle["cmap"] == "twilight" and (angle["vmin"], angle["vmax"]) == (-90.0, 90.0)
    cmap = matplotlib.colormaps[angle["cmap"]]
    assert np.allclose(cmap(0.0), cmap(1.0), atol=0.02)  # cyclic: -90 and +90 deg are one direction


def test_predict_uses_the_channels_own_map(tmp_path, capsys) -> None:
    """A per-colour PSF map file: ``predict --channel red`` registers (and blurs) with the red map,
    whose offset differs from the white one's (a lateral colour shift); ``--channel mean`` with the white."""
    from edofproj.procams.capture_io import write_rgb_png
    from edofproj.procams.psf_map import save_psf_maps

    tx, ty = camera_points()
    dark, bright = np.full(tx.shape, 0.05), np.full(tx.shape, 0.85)
    CorrespondenceMap(tx, ty, (H, W)).save(tmp_path / "map.npz", dark=dark.astype(np.float32),
                                           bright=bright.astype(np.float32))  # fmt: skip
    white, red = flat_psf_map(1.0, 1.5, (0.25, 0.5)), flat_psf_map(1.2, 1.8, (-0.5, 0.75))
    red.channel = "red"
    save_psf_maps(tmp_path / "psf.npz", [red, white])
    image = profiles_to_images(gray_code_profiles(W), (H, W), "x")[-3]
    write_rgb_png(tmp_path / "image.png", np.repeat(image[..., None], 3, -1))
    write_rgb_png(
        tmp_path / "capture.png",
        np.repeat((0.1 + 0.7 * sample_at_map(image, CorrespondenceMap(tx, ty, (H, W))))[..., None], 3, -1),
    )
    for channel, where in (("red", "-0.50, +0.75"), ("mean", "+0.25, +0.50"), ("green", "+0.25, +0.50")):
        code, out, err = run_cli(capsys, "procams", "predict", "--map", tmp_path / "map.npz", "--psf-map",
                                 tmp_path / "psf.npz", "--image", tmp_path / "image.png", "--capture",
                                 tmp_path / "capture.png", "--channel", channel)  # fmt: skip
        assert code == 0, err
        assert f"o = ({where})" in out, (channel, out)


# ------------------------------------------------------------------ another blur model, same registration
def test_prediction_takes_any_blur_of_the_projector_image() -> None:
    """A projector whose blur is a 1x7 box along the columns (no Gaussian): predicted with that box
    as ``light_blur`` the capture is reproduced (> 60 dB) at the PSF map's registration; with the
    PSF map's Gaussian (another width and shape) or without blur it is not (< 40 dB); the identity
    as ``light_blur`` is the prediction without blur, to rounding."""
    tx, ty = camera_points()
    truth = CorrespondenceMap(tx, ty, (H, W))
    psf_map = flat_psf_map(0.6, 0.6, OFFSET)
    image = profiles_to_images(gray_code_profiles(W), (H, W), "x")[-3]  # 8-px stripes

    def box(u: np.ndarray) -> np.ndarray:
        return ndimage.uniform_filter1d(u, 7, axis=1, mode="constant")

    dark, bright = np.full(tx.shape, 0.05), np.full(tx.shape, 0.85)
    capture = dark + (bright - dark) * sample_at_map(box(image), truth)
    px, py = tx + OFFSET[0], ty + OFFSET[1]
    inside = (px >= -0.5) & (px <= W - 0.5) & (py >= -0.5) & (py <= H - 0.5)
    corr = CorrespondenceMap(np.where(inside, px, np.nan), np.where(inside, py, np.nan), (H, W))
    common = dict(psf_map=psf_map, flat_filter_px=1)
    with_box = predict_capture(image, capture, corr, dark, bright, light_blur=box, **common)
    gaussian = predict_capture(image, capture, corr, dark, bright, **common)
    none = predict_capture(image, capture, corr, dark, bright, blur_psf=False, **common)
    identity = predict_capture(image, capture, corr, dark, bright, light_blur=lambda u: u, **common)
    assert with_box.offset_px == gaussian.offset_px == OFFSET
    assert with_box.psnr_db > 60.0 and abs(with_box.gain - 1.0) < 1e-3
    assert gaussian.psnr_db < 40.0 and none.psnr_db < 40.0
    assert identity.psnr_db == pytest.approx(none.psnr_db, abs=1e-9)
    with pytest.raises(EdofprojError, match="turned"):
        predict_capture(image, capture, corr, dark, bright, light_blur=lambda u: u[:-1], **common)
