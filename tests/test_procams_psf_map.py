"""PSFs from single-pixel dot captures that saturate and clip to black, the PSF map, and the
prediction of a capture from a map and a PSF map (on the virtual ProCams)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.prediction import (
    blur,
    fit_exposure,
    gaussian_kernel,
    predict_capture,
    sampling_kernel_covariance,
)
from edofproj.procams.psf_map import DotGrid, PSFMap, covariance, measure_psf_map
from edofproj.procams.structured_light import (
    CorrespondenceMap,
    decode_phase_shift,
    gray_code_profiles,
    phase_shift_profiles,
    profiles_to_images,
)
from edofproj.procams.virtual import VirtualProCams

SIGMAS = (1.2, 2.4)
THETA = math.radians(70.0)


def dot_scene(offset=(1.0, -0.6), top_fraction=0.35, black=-0.03, seed=0):
    """A camera seeing a 60x72 projector at 2 camera px per projector px, a grid of dots every 12 px
    blurred by one anisotropic Gaussian; the map it decodes is shifted by ``offset``; the capture
    saturates at ``top_fraction`` of a dot's peak and is clipped to black below ``black``."""
    H, W = 60, 72
    Hc, Wc = 2 * H, 2 * W
    v, u = np.mgrid[0:Hc, 0:Wc].astype(float)
    tx, ty = (u - 0.5) / 2, (v - 0.5) / 2
    inv = np.linalg.inv(covariance(SIGMAS[0], SIGMAS[1], THETA))
    light = np.zeros((Hc, Wc))
    for y0 in range(0, H, 12):
        for x0 in range(0, W, 12):
            dx, dy = tx - x0, ty - y0
            light += np.exp(-0.5 * (inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy))
    rng = np.random.default_rng(seed)
    capture = black + light + 0.003 * rng.standard_normal(light.shape)
    top = top_fraction
    capture = np.clip(capture, 0.0, top)
    corr = CorrespondenceMap(tx + offset[0], ty + offset[1], (H, W))
    return capture, corr, top, (H, W)


def test_censored_fit_recovers_the_anisotropic_psf_and_the_offset() -> None:
    capture, corr, top, hw = dot_scene()
    saturated, clipped = capture >= top, capture <= 0
    assert saturated.mean() > 0.005 and clipped.mean() > 0.3
    psf_map, fits = measure_psf_map(capture, corr, DotGrid.covering(hw, (12, 12)), top=top,
                                    saturated=saturated, clipped=clipped)  # fmt: skip
    assert np.allclose(psf_map.offset_px, (1.0, -0.6), atol=0.05)
    truth = covariance(SIGMAS[0], SIGMAS[1], THETA)
    sx, sy = math.sqrt(truth[0, 0]), math.sqrt(truth[1, 1])
    inner = psf_map.fitted
    assert inner.sum() >= 20
    assert np.allclose(np.median(psf_map.sigma_x[inner]), sx, rtol=0.05)
    assert np.allclose(np.median(psf_map.sigma_y[inner]), sy, rtol=0.05)
    assert abs(np.median(psf_map.angle_deg[inner]) + 20.0) < 3.0  # the major axis (sigma 2.4) at 70 + 90 deg
    # the same samples fitted as values (no censoring): the flat, saturated tops widen the PSF
    naive, _ = measure_psf_map(capture, corr, DotGrid.covering(hw, (12, 12)), top=top,
                               saturated=np.zeros_like(saturated), clipped=np.zeros_like(clipped))  # fmt: skip
    assert np.median(naive.sigma_x[naive.fitted]) > 1.15 * sx


def test_psf_map_round_trips_and_interpolates_covariances(tmp_path) -> None:
    capture, corr, top, hw = dot_scene()
    psf_map, _ = measure_psf_map(capture, corr, DotGrid.covering(hw, (12, 12)), top=top)
    psf_map.save(tmp_path / "p.npz")
    loaded = PSFMap.load(tmp_path / "p.npz")
    assert np.allclose(loaded.cov, psf_map.cov) and loaded.projector_hw == hw
    mid = loaded.covariance_at(np.array(0.5 * (loaded.xs[0] + loaded.xs[1])), np.array(loaded.ys[0]))
    assert np.allclose(mid, 0.5 * (loaded.cov[0, 0] + loaded.cov[0, 1]))
    np.savez(tmp_path / "x.npz", format=np.array("edofproj-procams-psf-map"), xs=np.arange(2.0))
    with pytest.raises(EdofprojError, match="lacks"):
        PSFMap.load(tmp_path / "x.npz")


def test_blur_is_the_gaussian_and_keeps_the_light() -> None:
    cov = covariance(1.0, 2.0, 0.3)
    psf_map = PSFMap(xs=np.array([0.0, 47.0]), ys=np.array([0.0, 39.0]), cov=np.broadcast_to(cov, (2, 2, 2, 2)).copy(),
                     offset_px=np.zeros(2), fitted=np.ones((2, 2), bool), projector_hw=(40, 48))  # fmt: skip
    image = np.zeros((40, 48))
    image[20, 24] = 1.0
    out = blur(image, psf_map, tile_px=8)
    assert math.isclose(out.sum(), 1.0, rel_tol=1e-9)
    kernel = gaussian_kernel(sampling_kernel_covariance(cov))
    r = kernel.shape[0] // 2
    assert np.allclose(out[20 - r : 20 + r + 1, 24 - r : 24 + r + 1], kernel, atol=1e-12)
    # sampled bilinearly (a tent of variance 1/6 around each sample), the light spreads by the PSF's S
    for axis, centre in ((0, 24), (1, 20)):
        marginal = out.sum(axis=axis)
        k = np.arange(len(marginal))
        variance = float(np.sum(marginal * (k - centre) ** 2)) + 1 / 6
        assert math.isclose(variance, cov[axis, axis], rel_tol=0.01)


def test_exposure_fit_ignores_clipped_pixels() -> None:
    rng = np.random.default_rng(0)
    model = rng.uniform(0, 1, (50, 50))
    capture = np.clip(1.6 * model - 0.2, 0, 1)  # the capture clips at both ends
    gain, offset = fit_exposure(model, capture, np.ones_like(model, bool))
    assert math.isclose(gain, 1.6, rel_tol=1e-6) and math.isclose(offset, -0.2, abs_tol=1e-6)


# --------------------------------------------------------------------- the virtual ProCams
PROJ_HW = (72, 96)


def anisotropic_psf(sigma_x: float, sigma_y: float, size: int = 15) -> np.ndarray:
    r = size // 2
    y, x = np.mgrid[-r : r + 1, -r : r + 1].astype(float)
    k = np.exp(-0.5 * ((x / sigma_x) ** 2 + (y / sigma_y) ** 2))
    return np.repeat((k / k.sum())[None], 3, axis=0)


def captures(rig, images, rng) -> np.ndarray:
    return np.stack([rig.capture(np.repeat(im[..., None], 3, -1), rng).mean(-1) for im in images]).astype(float)


def virtual_prediction(sigmas=(1.0, 2.0), seed: int = 0):
    """Map (phase shift), PSF map (dots every 12 px), dark and bright levels (black and white fields)
    and the prediction of the finest Gray-code plane (2-px stripes), captured with another exposure,
    on a virtual ProCams."""
    rig = VirtualProCams.example(PROJ_HW, anisotropic_psf(*sigmas), seed=seed, camera_scale=2.0, gamma=1.0,
                                 radial_k1=0.0, noise_sigma=0.003, projector_black=0.0)  # fmt: skip
    rng = np.random.default_rng(seed)
    H, W = PROJ_HW
    x = decode_phase_shift(captures(rig, profiles_to_images(phase_shift_profiles(W, [1, 4, 16], 4), PROJ_HW, "x"), rng),
                           [1, 4, 16], 4, W)  # fmt: skip
    y = decode_phase_shift(captures(rig, profiles_to_images(phase_shift_profiles(H, [1, 4, 12], 4), PROJ_HW, "y"), rng),
                           [1, 4, 12], 4, H)  # fmt: skip
    corr = CorrespondenceMap.from_decodings(x, y, PROJ_HW)
    dots = np.zeros(PROJ_HW)
    dots[::12, ::12] = 1.0
    dot_capture = captures(rig, dots[None], rng)[0]
    psf_map, _ = measure_psf_map(dot_capture, corr, DotGrid.covering(PROJ_HW, (12, 12)))
    finest = profiles_to_images(gray_code_profiles(W), PROJ_HW, "x")[-1]
    white, black, gray = captures(rig, np.stack([np.ones(PROJ_HW), np.zeros(PROJ_HW), finest]), rng)
    capture = np.clip(0.8 * gray + 0.05, 0, 1)  # another exposure
    with_psf = predict_capture(finest, capture, corr, black, white, psf_map)
    without = predict_capture(finest, capture, corr, black, white, None, offset_px=tuple(psf_map.offset_px))
    return psf_map, with_psf, without


def test_prediction_on_the_virtual_procams_needs_the_psf() -> None:
    psf_map, with_psf, without = virtual_prediction()
    fitted = psf_map.fitted
    # the rig's camera integrates over half a projector pixel: the measured widths include it
    assert 0.9 < np.median(psf_map.sigma_x[fitted]) < 1.25
    assert 1.85 < np.median(psf_map.sigma_y[fitted]) < 2.25
    assert np.all(np.abs(psf_map.offset_px) < 0.2)  # this rig's phase origin is at pixel centre 0
    assert with_psf.psnr_db > 38.0
    assert with_psf.psnr_db > without.psnr_db + 5.0
    assert with_psf.ssim > without.ssim
    # the finest plane keeps about a quarter of its contrast and its dark and bright levels are nearly
    # uniform: the gain trades off against the model's contrast, and is known to about 10 % only
    assert math.isclose(with_psf.gain, 0.8, rel_tol=0.15) and math.isclose(with_psf.offset, 0.05, abs_tol=0.05)


def test_a_psf_as_small_as_the_camera_pixels_still_helps() -> None:
    # the measured widths contain the camera's integration; blur and bilinear sampling must not add
    # the interpolation's own spread on top of them
    psf_map, with_psf, without = virtual_prediction((0.6, 0.6))
    assert with_psf.psnr_db > without.psnr_db + 0.8


# --------------------------------------------------------------------- per-colour PSF maps
COLOUR_SIGMAS = {"mean": (1.1, 1.8), "red": (0.9, 1.4), "green": (1.3, 2.0), "blue": (1.8, 2.7)}


def colour_dot_lab(folder) -> None:
    """A lab folder with a white dot capture and a red, a green and a blue one of a 60x72 projector seen
    at 2 camera px per projector px: each colour's dots blurred by its own Gaussian (``COLOUR_SIGMAS``)
    in the camera's channel of that colour, and leaking into the other two channels with another,
    wider blur (a channel read by mistake gives another width); a map file ``map.npz``."""
    from edofproj.procams.capture_io import write_rgb_png

    H, W = 60, 72
    v, u = np.mgrid[0 : 2 * H, 0 : 2 * W].astype(float)
    tx, ty = (u - 0.5) / 2, (v - 0.5) / 2

    def dots(sigma_x: float, sigma_y: float) -> np.ndarray:
        light = np.zeros_like(tx)
        for y0 in range(0, H, 12):
            for x0 in range(0, W, 12):
                light += np.exp(-0.5 * (((tx - x0) / sigma_x) ** 2 + ((ty - y0) / sigma_y) ** 2))
        return light

    leak = 0.3 * dots(3.5, 3.5)
    for name, (sx, sy) in COLOUR_SIGMAS.items():
        own = 0.02 + 0.8 * dots(sx, sy)
        if name == "mean":
            rgb = np.repeat(own[..., None], 3, -1)
        else:
            rgb = np.repeat((0.02 + leak)[..., None], 3, -1)
            rgb[..., ("red", "green", "blue").index(name)] = own
        write_rgb_png(folder / f"dots_{name}.png", np.clip(rgb, 0, 1))
    sequences = [
        {"name": f"dots_{name}", "kind": "dots", "spacing_px": [12, 12], "files": {"list": [f"dots_{name}.png"]}}
        | ({} if name == "mean" else {"channel": name})
        for name in COLOUR_SIGMAS
    ]
    data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": H, "width": W},
            "sequences": sequences}  # fmt: skip
    (folder / "lab.json").write_text(json.dumps(data), encoding="utf-8")
    CorrespondenceMap(tx, ty, (H, W)).save(folder / "map.npz")


def test_per_colour_maps_recover_three_known_widths(tmp_path, capsys) -> None:
    from edofproj.cli import main
    from edofproj.procams.psf_map import load_psf_maps, psf_maps_for_rgb

    colour_dot_lab(tmp_path)
    out = tmp_path / "psf.npz"
    code = main(["procams", "psf-map", "--lab", str(tmp_path / "lab.json"), "--map", str(tmp_path / "map.npz"),
                 "--dots", "dots_blue", "dots_mean", "dots_red", "dots_green", "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    maps = load_psf_maps(out)
    assert list(maps) == ["mean", "red", "green", "blue"]
    for name, (sx, sy) in COLOUR_SIGMAS.items():
        m = maps[name]
        assert m.channel == name and m.fitted.sum() >= 20
        assert math.isclose(np.median(m.sigma_x[m.fitted]), sx, rel_tol=0.05), name
        assert math.isclose(np.median(m.sigma_y[m.fitted]), sy, rel_tol=0.05), name
    assert PSFMap.load(out).channel == "mean" and PSFMap.load(out, "blue").channel == "blue"
    assert [m.channel for m in psf_maps_for_rgb(maps)] == ["red", "green", "blue"]
    # two sequences of one colour are refused in one line
    code = main(["procams", "psf-map", "--lab", str(tmp_path / "lab.json"), "--map", str(tmp_path / "map.npz"),
                 "--dots", "dots_red", "dots_red", "--out", str(tmp_path / "p2.npz")])  # fmt: skip
    assert code != 0 and "channel 'red'" in capsys.readouterr().err and not (tmp_path / "p2.npz").exists()


def test_a_single_map_file_without_channels_still_loads(tmp_path) -> None:
    """A map written before per-colour maps (no ``channels`` key) is one ``mean`` map; a colour's map it
    lacks is one line; the RGB planes all use it."""
    from edofproj.procams.psf_map import load_psf_maps, psf_maps_for_rgb

    cov = np.broadcast_to(covariance(1.0, 2.0, 0.3), (2, 3, 2, 2)).copy()
    np.savez(tmp_path / "old.npz", format=np.array("edofproj-procams-psf-map"), xs=np.array([0.0, 10.0, 20.0]),
             ys=np.array([0.0, 10.0]), cov=cov, offset_px=np.array([0.5, -0.5]), fitted=np.ones((2, 3), bool),
             projector_hw=np.array([20, 30]))  # fmt: skip
    maps = load_psf_maps(tmp_path / "old.npz")
    assert list(maps) == ["mean"] and np.allclose(maps["mean"].cov, cov)
    assert all(m is maps["mean"] for m in psf_maps_for_rgb(maps))
    with pytest.raises(EdofprojError, match="no map for channel 'red'"):
        PSFMap.load(tmp_path / "old.npz", "red")
