"""The traps a lab hit first on the lab path (issue 56, item 5), each on synthetic captures: one
registration for predictions with and without blur, the exposure fit of a mostly black dot capture,
decoding a subset of period counts, psf-map's progress, its figure's colour scales and its summary."""

from __future__ import annotations

import re

import numpy as np

from edofproj.cli import main
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
