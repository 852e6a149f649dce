"""Calibration patterns: contents, the manifest, and its round trip through files."""

import numpy as np
import pytest

from edofproj.errors import EdofprojError
from edofproj.procams.capture_io import read_rgb
from edofproj.procams.patterns import PatternManifest, PatternSpec, build_pattern_set, color_sample_values, parse_grid


@pytest.fixture(scope="module")
def pattern_set():
    return build_pattern_set(
        PatternSpec(width=80, height=48, bernoulli_count=3, dot_grid=(3, 5), color_levels=3, seed=7)
    )


def test_roles_and_counts(pattern_set):
    manifest, images = pattern_set
    assert len(manifest.with_role("bernoulli")) == 3
    assert len(manifest.with_role("color_sample")) == 3**3
    assert [manifest.primary(n).file for n in ("red", "green", "blue")] == ["red.png", "green.png", "blue.png"]
    assert manifest.one("white").color == (1.0, 1.0, 1.0) and manifest.one("black").color == (0.0, 0.0, 0.0)
    assert set(images) == {e.file for e in manifest.entries}
    assert all(image.shape == (48, 80, 3) for image in images.values())


def test_bernoulli_patterns_are_fair_independent_coin_flips(pattern_set):
    manifest, images = pattern_set
    noise = np.stack([images[e.file] for e in manifest.with_role("bernoulli")])
    assert set(np.unique(noise)) == {0.0, 1.0}
    assert abs(noise.mean() - 0.5) < 0.02
    channels = noise.reshape(-1, 3).T
    assert np.abs(np.corrcoef(channels) - np.eye(3)).max() < 0.03


def test_bernoulli_spectrum_is_flat():
    """White noise: the same expected power at every non-zero frequency, so Eq. 13 is equally well
    conditioned everywhere (blocks of pixels would have spectral zeros)."""
    manifest, images = build_pattern_set(PatternSpec(width=128, height=128, bernoulli_count=5, dot_grid=(2, 2)))
    noise = np.stack([images[e.file][..., 0] for e in manifest.with_role("bernoulli")])
    power = (np.abs(np.fft.fft2(noise - noise.mean(axis=(1, 2), keepdims=True))) ** 2).mean(axis=0)
    fy, fx = np.meshgrid(np.fft.fftfreq(128), np.fft.fftfreq(128), indexing="ij")
    radius = np.hypot(fx, fy)
    bands = [power[(radius > lo) & (radius <= lo + 0.1)].mean() for lo in (0.0, 0.1, 0.2, 0.3, 0.4)]
    expected = 128 * 128 / 4  # N * variance
    np.testing.assert_allclose(bands, expected, rtol=0.05)


def test_dots_are_centred_on_the_listed_centres(pattern_set):
    manifest, images = pattern_set
    dots = manifest.one("dots")
    assert dots.grid == (3, 5) and dots.dots.shape == (15, 2)
    image = images["dots.png"][..., 0]
    r = dots.radius_px
    counts = []
    for x, y in dots.dots.astype(int):
        window = image[y - r - 1 : y + r + 2, x - r - 1 : x + r + 2]
        rows, cols = np.nonzero(window)
        assert rows.mean() - (r + 1) == 0 and cols.mean() - (r + 1) == 0
        counts.append(rows.size)
    assert len(set(counts)) == 1 and np.count_nonzero(image) == sum(counts)  # 15 equal discs, nothing else


def test_color_samples_are_exact_8_bit_levels():
    values = color_sample_values(6)
    assert values.shape == (216, 3)
    np.testing.assert_array_equal(values * 255, np.round(values * 255))
    assert sorted(set(values[:, 0] * 255)) == [0, 51, 102, 153, 204, 255]


def test_seed_fixes_the_noise():
    a = build_pattern_set(PatternSpec(width=32, height=32, seed=1, dot_grid=(2, 2)))[1]["bernoulli_00.png"]
    b = build_pattern_set(PatternSpec(width=32, height=32, seed=1, dot_grid=(2, 2)))[1]["bernoulli_00.png"]
    c = build_pattern_set(PatternSpec(width=32, height=32, seed=2, dot_grid=(2, 2)))[1]["bernoulli_00.png"]
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)


def test_cli_writes_files_that_match_the_manifest(tmp_path):
    from edofproj.cli import main

    out = tmp_path / "patterns"
    assert (
        main(
            [
                "procams",
                "patterns",
                "--width",
                "80",
                "--height",
                "48",
                "--out",
                str(out),
                "--dots",
                "3x5",
                "--color-levels",
                "2",
                "--bernoulli",
                "2",
                "--seed",
                "7",
            ]
        )
        == 0
    )
    manifest = PatternManifest.load(out)
    assert (manifest.width, manifest.height) == (80, 48)
    _, images = build_pattern_set(
        PatternSpec(width=80, height=48, bernoulli_count=2, dot_grid=(3, 5), color_levels=2, seed=7)
    )
    for entry in manifest.entries:
        np.testing.assert_array_equal(read_rgb(out / entry.file), images[entry.file])
    np.testing.assert_array_equal(
        manifest.one("dots").dots,
        build_pattern_set(PatternSpec(width=80, height=48, dot_grid=(3, 5)))[0].one("dots").dots,
    )


def test_bad_specs_raise_one_line():
    with pytest.raises(EdofprojError, match="does not fit"):
        build_pattern_set(PatternSpec(width=64, height=48, dot_grid=(16, 32)))
    with pytest.raises(EdofprojError, match="ROWSxCOLS"):
        parse_grid("16by32")
    with pytest.raises(EdofprojError, match="--bernoulli 0"):
        build_pattern_set(PatternSpec(width=64, height=48, bernoulli_count=0))
