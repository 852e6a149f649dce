"""Structured light on synthetic captures that misbehave like real ones: the virtual ProCams (an
independent image formation: projector response, PSF, camera homography, pixel integration, noise)
renders the patterns; saturation, clipped black, exposure drift, 2x2 demosaicing and a camera moved
between sessions are applied to its captures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.camera_motion import carry_map
from edofproj.procams.geometry import apply_homography
from edofproj.procams.structured_light import (
    CorrespondenceMap,
    decode_gray_code,
    decode_phase_shift,
    gray_code_bits,
    gray_code_profiles,
    phase_shift_profiles,
    profiles_to_images,
)
from edofproj.procams.virtual import VirtualProCams

PROJ_HW = (72, 96)
PERIODS_X = [1, 4, 16]
PERIODS_Y = [1, 4, 12]


def gaussian_psf(sigma_x: float, sigma_y: float, size: int = 15) -> np.ndarray:
    r = size // 2
    y, x = np.mgrid[-r : r + 1, -r : r + 1].astype(float)
    k = np.exp(-0.5 * ((x / sigma_x) ** 2 + (y / sigma_y) ** 2))
    return np.repeat((k / k.sum())[None], 3, axis=0)


def make_rig(seed: int = 0, **params) -> VirtualProCams:
    base = dict(gamma=1.0, radial_k1=0.0, noise_sigma=0.003, camera_scale=2.0, projector_black=0.0)
    base.update(params)
    return VirtualProCams.example(PROJ_HW, gaussian_psf(0.6, 0.6), seed=seed, **base)


def grey_captures(rig: VirtualProCams, images: np.ndarray, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([rig.capture(np.repeat(im[..., None], 3, axis=-1), rng).mean(axis=-1) for im in images]).astype(
        np.float64
    )


def phase_frames(rig, axis: str, periods) -> np.ndarray:
    length = PROJ_HW[1] if axis == "x" else PROJ_HW[0]
    return grey_captures(rig, profiles_to_images(phase_shift_profiles(length, periods, 4), PROJ_HW, axis))


def gray_frames(rig, axis: str = "x") -> np.ndarray:
    length = PROJ_HW[1] if axis == "x" else PROJ_HW[0]
    return grey_captures(rig, profiles_to_images(gray_code_profiles(length), PROJ_HW, axis))


def truth(rig) -> tuple[np.ndarray, np.ndarray]:
    Hc, Wc = rig.camera_hw
    v, u = np.mgrid[0:Hc, 0:Wc].astype(float)
    return rig.camera_points_to_projector(u, v)


def inside(x, y, margin: float = 2.0) -> np.ndarray:
    H, W = PROJ_HW
    return (x > margin) & (x < W - 1 - margin) & (y > margin) & (y < H - 1 - margin)


# ------------------------------------------------------------------------------- patterns
def test_gray_code_every_boundary_is_an_edge_in_exactly_one_plane() -> None:
    profiles = gray_code_profiles(912)
    assert profiles.shape == (gray_code_bits(912), 912) == (10, 912)
    changes = np.abs(np.diff(profiles, axis=1)).sum(axis=0)
    assert np.all(changes == 1)
    # plane 7 (0-based; the 8th) is made of 8-px stripes, plane 9 of 2-px stripes
    for plane, width in ((7, 8), (8, 4), (9, 2)):
        edges = np.flatnonzero(np.diff(profiles[plane]))
        assert np.all(np.diff(edges) == width)


def test_ideal_codes_decode_exactly_and_held_out_planes_give_stripe_centres() -> None:
    length = 100
    # (n, 3, L): a camera that sees one projector row three times (each pixel's decoding is checked
    # against its neighbours': the middle row's are all in the image)
    gray = np.repeat(gray_code_profiles(length)[:, None, :], 3, axis=1)
    full = decode_gray_code(gray, length, min_contrast=0.5)
    # without inverse patterns, a column dark (0) or lit (85: g = 127) in every plane has no threshold
    undecodable = np.flatnonzero(gray.min(axis=0)[1] == gray.max(axis=0)[1])
    assert undecodable.tolist() == [0, 85]
    decodable = np.setdiff1d(np.arange(length), undecodable)
    assert np.array_equal(full.coordinate[1, decodable], decodable)
    assert not full.valid[1, undecodable].any()
    coarse = decode_gray_code(gray[:4], length, min_contrast=0.5)
    width = 2 ** (gray_code_bits(length) - 4)
    c = np.arange(length)
    expected = (c // width) * width + (width - 1) / 2
    ok = coarse.valid[1]
    assert ok.sum() >= length - 2 * width - 4  # the stripes dark or lit in all 4 planes are not decodable
    assert np.array_equal(coarse.coordinate[1, ok], expected[ok])
    phase = 0.1 + 0.8 * np.repeat(
        phase_shift_profiles(length, [1, 4, 16], 4)[:, None, :], 3, axis=1
    )  # 0 and 1 read as clipped
    decoded = decode_phase_shift(phase, [1, 4, 16], 4, length, min_modulation=0.1)
    assert np.allclose(decoded.coordinate[1], c, atol=1e-9)


def test_phase_plan_is_checked() -> None:
    with pytest.raises(EdofprojError, match="start at 1"):
        phase_shift_profiles(100, [4, 16], 4)
    with pytest.raises(EdofprojError, match="at least 3 steps"):
        phase_shift_profiles(100, [1, 4], 2)


# ------------------------------------------------------------------------------- decoding a rig
def test_phase_shift_and_gray_code_give_the_rig_map() -> None:
    rig = make_rig()
    x = decode_phase_shift(phase_frames(rig, "x", PERIODS_X), PERIODS_X, 4, PROJ_HW[1])
    y = decode_phase_shift(phase_frames(rig, "y", PERIODS_Y), PERIODS_Y, 4, PROJ_HW[0])
    corr = CorrespondenceMap.from_decodings(x, y, PROJ_HW)
    tx, ty = truth(rig)
    region = inside(tx, ty)
    assert corr.valid[region].mean() > 0.95
    ok = region & corr.valid
    # a projector pixel is flat: the truth varies by +-0.5 px within it
    assert np.median(np.abs(corr.proj_x[ok] - tx[ok])) < 0.3
    assert np.median(np.abs(corr.proj_y[ok] - ty[ok])) < 0.3
    _, residual, inliers = corr.fit_homography(ransac_px=0.5)
    assert np.median(residual[inliers]) < 0.3
    gray = decode_gray_code(gray_frames(rig), PROJ_HW[1])
    good = region & gray.valid
    assert gray.valid[region].mean() > 0.9
    assert np.mean(np.abs(gray.coordinate[good] - tx[good]) <= 1.0) > 0.97


def test_gray_code_survives_exposure_drift_between_frames() -> None:
    rig = make_rig(ambient=(0.05, 0.05, 0.05))
    frames = gray_frames(rig)
    rng = np.random.default_rng(3)
    gains = rng.uniform(0.35, 1.0, len(frames))
    offsets = rng.uniform(0.0, 0.3, len(frames))
    drifted = np.clip(frames * gains[:, None, None] + offsets[:, None, None], 0, 1)
    tx, ty = truth(rig)
    region = inside(tx, ty)

    def right(decoding) -> float:
        return float(
            np.mean(decoding.valid[region] & (np.abs(np.nan_to_num(decoding.coordinate - tx, nan=99))[region] <= 1.0))
        )

    assert right(decode_gray_code(drifted, PROJ_HW[1])) > 0.95
    assert right(decode_gray_code(drifted, PROJ_HW[1], normalize_exposure=False)) < 0.9


def test_saturated_or_clipped_samples_make_phase_pixels_invalid_not_wrong() -> None:
    rig = make_rig()
    frames = phase_frames(rig, "x", PERIODS_X)
    ramp = np.linspace(0.0, 1.0, frames.shape[2])[None, None, :]  # left to right across the camera
    bright = np.clip(frames * (1.0 + 1.5 * ramp), 0, 1)  # the right part saturates where the sinusoids peak
    dark = np.clip(frames - 0.4 * ramp, 0, 1)  # the right part is clipped to black where they dip
    tx, ty = truth(rig)
    region = inside(tx, ty)
    for misbehaving in (bright, dark):
        x = decode_phase_shift(misbehaving, PERIODS_X, 4, PROJ_HW[1])
        ok = x.valid & region
        assert 0 < ok.sum() < region.sum()
        assert np.percentile(np.abs(x.coordinate[ok] - tx[ok]), 99) < 0.5


def demosaic_2x2(rgb: np.ndarray) -> np.ndarray:
    """An RGGB mosaic of ``rgb`` and its crudest demosaicing: each 2x2 block takes its one R, the mean
    of its two Gs and its one B (half a pixel of colour shift, blocky)."""
    H, W, _ = rgb.shape
    H2, W2 = H // 2 * 2, W // 2 * 2
    out = rgb.copy()
    r = rgb[0:H2:2, 0:W2:2, 0]
    g = 0.5 * (rgb[0:H2:2, 1:W2:2, 1] + rgb[1:H2:2, 0:W2:2, 1])
    b = rgb[1:H2:2, 1:W2:2, 2]
    for c, plane in enumerate((r, g, b)):
        out[:H2, :W2, c] = np.repeat(np.repeat(plane, 2, axis=0), 2, axis=1)
    return out


def test_decoding_after_a_2x2_demosaicing() -> None:
    rig = make_rig()
    rng = np.random.default_rng(1)
    images = profiles_to_images(phase_shift_profiles(PROJ_HW[1], PERIODS_X, 4), PROJ_HW, "x")
    frames = np.stack([demosaic_2x2(rig.capture(np.repeat(im[..., None], 3, -1), rng)).mean(-1) for im in images])
    x = decode_phase_shift(frames.astype(np.float64), PERIODS_X, 4, PROJ_HW[1])
    tx, ty = truth(rig)
    ok = x.valid & inside(tx, ty)
    assert ok.sum() > 0.9 * inside(tx, ty).sum()
    # two camera px per projector px: a block of 2x2 camera pixels moves a sample by <= 0.5 projector px
    # (and a projector pixel is flat: the truth varies by +-0.5 px within it)
    assert np.median(np.abs(x.coordinate[ok] - tx[ok])) < 0.4


def test_a_map_carried_to_a_moved_camera_matches_that_camera() -> None:
    before = make_rig()
    angle = math.radians(1.5)
    motion = np.array([[math.cos(angle), -math.sin(angle), 6.0], [math.sin(angle), math.cos(angle), -4.0], [0, 0, 1]])
    after = VirtualProCams(
        projector_hw=before.projector_hw,
        camera_hw=before.camera_hw,
        psf=before.psf,
        homography=motion @ before.homography,
        radial_k1=0.0,
        gamma=1.0,
        projector_black=0.0,
        noise_sigma=0.003,
    )
    x = decode_phase_shift(phase_frames(before, "x", PERIODS_X), PERIODS_X, 4, PROJ_HW[1])
    y = decode_phase_shift(phase_frames(before, "y", PERIODS_Y), PERIODS_Y, 4, PROJ_HW[0])
    reference = CorrespondenceMap.from_decodings(x, y, PROJ_HW)
    bright_before = 0.5 * (x.bright + y.bright)
    coarse = decode_gray_code(gray_frames(after)[:4], PROJ_HW[1])  # 8-px stripes only
    carried, G = carry_map(reference, bright_before, coarse, "x", coarse.bright)
    corners = np.array([[0, 0], [255, 0], [255, 191], [0, 191]], dtype=float)
    assert np.abs(apply_homography(G, corners) - apply_homography(np.linalg.inv(motion), corners)).max() < 0.5
    tx, ty = truth(after)
    ok = carried.valid & inside(tx, ty)
    assert ok.sum() > 0.8 * inside(tx, ty).sum()
    assert np.median(np.abs(carried.proj_x[ok] - tx[ok])) < 0.35
    assert np.median(np.abs(carried.proj_y[ok] - ty[ok])) < 0.5
    # the map of the camera before the move is wrong for the camera after it
    stale = reference.valid & inside(tx, ty)
    assert np.median(np.abs(reference.proj_x[stale] - tx[stale])) > 1.0


def test_correspondence_map_round_trips_and_bad_files_fail(tmp_path) -> None:
    proj_x = np.array([[0.0, 1.5], [np.nan, 3.0]])
    corr = CorrespondenceMap(proj_x, proj_x * 0.5, (4, 4))
    corr.save(tmp_path / "m.npz")
    loaded = CorrespondenceMap.load(tmp_path / "m.npz")
    assert np.array_equal(np.isnan(loaded.proj_x), np.isnan(proj_x))
    assert loaded.projector_hw == (4, 4)
    CorrespondenceMap(proj_x * 10, proj_x, (4, 4)).save(tmp_path / "bad.npz")
    with pytest.raises(EdofprojError, match="outside"):
        CorrespondenceMap.load(tmp_path / "bad.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(2))
    with pytest.raises(EdofprojError, match="not a correspondence map"):
        CorrespondenceMap.load(tmp_path / "other.npz")
