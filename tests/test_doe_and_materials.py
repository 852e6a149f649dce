"""Quantization, materials, spectra, DOE files."""

import numpy as np
import pytest
import torch

from edofproj.config import Config
from edofproj.doe import build_doe, load_doe, save_doe
from edofproj.doe.quantization import quantize_levels, wrap_and_quantize
from edofproj.errors import EdofprojError
from edofproj.optics.materials import height_2pi_m, refractive_index
from edofproj.optics.spectra import Spectrum


def test_fused_silica_index_at_the_sodium_d_line():
    assert float(refractive_index(587.6e-9)) == pytest.approx(1.4585, abs=1e-4)


def test_sixteen_level_step_is_about_75_nm():
    # docs/physics.md: h_2pi / 16 ~ 75 nm near 552 nm (the paper's 75/150/300/600 nm etch steps)
    assert height_2pi_m(552e-9) / 16 == pytest.approx(75e-9, abs=1e-9)


@pytest.mark.parametrize("levels", [2, 4, 16])
def test_quantized_heights_take_exactly_n_values(levels):
    h2pi = 1.2e-6
    raw = torch.linspace(-3e-6, 5e-6, 10001, dtype=torch.float64)
    q = wrap_and_quantize(raw, h2pi, levels)
    values = torch.unique(q)
    assert len(values) == levels
    assert torch.allclose(values, torch.arange(levels, dtype=torch.float64) * h2pi / levels)
    # straight-through: the gradient passes as if there were no quantizer
    raw.requires_grad_(True)
    wrap_and_quantize(raw, h2pi, levels).sum().backward()
    assert torch.all(raw.grad == 1)


def test_design_levels_of_a_trained_style_doe():
    doe = build_doe(Config(), "axicon")
    r = torch.linspace(0, doe.aperture_radius_m, 20000, dtype=torch.float64)
    levels = quantize_levels(doe.height_m(r), doe.h2pi_m, doe.levels)
    assert sorted(torch.unique(levels).tolist()) == list(range(16))


def test_untrained_mlp_doe_is_the_bare_lens():
    doe = build_doe(Config(), "mlp")
    h = doe.height_m(torch.linspace(0, doe.aperture_radius_m, 100, dtype=torch.float64))
    assert torch.all(h == h[0])  # constant height: only a piston phase


@pytest.mark.parametrize("kind", ["axicon", "multifocal", "cubic"])
def test_doe_file_round_trip(tmp_path, kind):
    doe = build_doe(Config(), kind)
    save_doe(doe, tmp_path / "d.npz", samples=256)
    back = load_doe(tmp_path / "d.npz")
    if doe.radially_symmetric:
        r = torch.as_tensor(np.linspace(0, doe.aperture_radius_m, 128, endpoint=False) + doe.aperture_radius_m / 256)
        assert torch.allclose(back.height_m(r), doe.height_m(r))
    else:
        c = (torch.arange(256, dtype=torch.float64) - 128 + 0.5) * 2 * doe.aperture_radius_m / 256
        y, x = torch.meshgrid(c, c, indexing="ij")
        assert torch.allclose(back.height_map_m(x, y), doe.height_map_m(x, y))


def test_doe_file_with_nan_heights_is_refused(tmp_path):
    doe = build_doe(Config(), "axicon")
    save_doe(doe, tmp_path / "d.npz", samples=64)
    data = dict(np.load(tmp_path / "d.npz"))
    data["height_m"][3] = np.nan
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(EdofprojError, match="NaN"):
        load_doe(tmp_path / "bad.npz")


def test_led_spectrum_weights_peak_at_the_primaries():
    s = Spectrum.led(np.arange(400, 701, 30))
    assert np.allclose(s.weights.sum(axis=1), 1)
    peaks = s.wavelengths_m[np.argmax(s.weights, axis=1)] * 1e9
    assert np.allclose(peaks, [610, 520, 460])  # nearest 30-nm samples to 620, 530, 460 nm


def test_measured_spd_csv(tmp_path):
    csv = tmp_path / "spd.csv"
    lam = np.arange(380, 721, 5)
    r = np.exp(-0.5 * ((lam - 640) / 10) ** 2)
    g = np.exp(-0.5 * ((lam - 550) / 10) ** 2)
    b = np.exp(-0.5 * ((lam - 430) / 10) ** 2)
    np.savetxt(csv, np.c_[lam, r, g, b], delimiter=",", header="wavelength_nm,r,g,b")
    s = Spectrum.from_csv(csv, np.arange(400, 701, 30))
    assert np.allclose(s.wavelengths_m[np.argmax(s.weights, axis=1)] * 1e9, [640, 550, 430])
    with pytest.raises(EdofprojError, match="cannot read SPD file"):
        Spectrum.from_csv(tmp_path / "missing.csv", [500])


def test_a_design_finer_than_the_pupil_sampling_is_refused_by_the_2d_engine_and_exact_in_the_radial_one(tmp_path):
    from edofproj.errors import SamplingError
    from edofproj.optics.fourier_engine import FourierPSFEngine
    from edofproj.optics.geometry import ProjectorGeometry
    from edofproj.optics.radial_engine import RadialPSFEngine

    doe = build_doe(Config(), "axicon")
    save_doe(doe, tmp_path / "d.npz", samples=1024)  # 512 rings of 6.84 um
    fine = load_doe(tmp_path / "d.npz")
    engine = FourierPSFEngine(ProjectorGeometry(), [550e-9], window=9, pupil_samples=512)
    with pytest.raises(SamplingError, match=r"rings 6\.84 um wide .* use pupil_samples >= 1024"):
        engine.psf(fine, [0.5])
    # the radial engine splits its rings at the design's edges: the same PSF at 512 and 1024 samples
    coarse = RadialPSFEngine(ProjectorGeometry(), [550e-9], window=9, pupil_samples=512).psf(fine, [0.5])
    resolved = RadialPSFEngine(ProjectorGeometry(), [550e-9], window=9, pupil_samples=1024).psf(fine, [0.5])
    assert float((coarse - resolved).abs().sum()) < 1e-6
