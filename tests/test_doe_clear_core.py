"""A learned DOE with a clear core (``doe.clear_core_fraction``): zero height inside, the DOE outside,
checked against the closed form of the on-axis focus of a two-zone pupil."""

from __future__ import annotations

import math

import pytest
import torch

from edofproj.config import Config
from edofproj.doe.factory import build_doe
from edofproj.doe.mlp import FreeRadialDOE, RadialMLPDOE
from edofproj.errors import ConfigError
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.materials import refractive_index
from edofproj.optics.radial_engine import RadialPSFEngine

GEO = ProjectorGeometry()
R = GEO.aperture_radius_m


@pytest.mark.parametrize("kind", ["mlp", "free"])
def test_heights_are_zero_inside_the_core_and_the_designs_outside(kind):
    torch.manual_seed(0)
    plain = RadialMLPDOE(R, frequencies=4) if kind == "mlp" else FreeRadialDOE(R, rings=64)
    for p in plain.parameters():
        torch.nn.init.normal_(p, std=0.5)
    cored = (
        RadialMLPDOE(R, frequencies=4, clear_core_fraction=0.6)
        if kind == "mlp"
        else FreeRadialDOE(R, rings=64, clear_core_fraction=0.6)
    )
    cored.load_state_dict(plain.state_dict())
    r = torch.linspace(0, R, 1001, dtype=torch.float64)
    inside = r < 0.6 * R
    assert torch.all(cored.raw_height_m(r)[inside] == 0)
    assert torch.equal(cored.raw_height_m(r)[~inside], plain.raw_height_m(r)[~inside])
    assert torch.all(cored.height_m(r)[inside] == 0)  # level 0 after wrapping and quantization


def test_a_half_wave_annulus_of_equal_area_darkens_the_focus_as_the_two_zones_interfere():
    """Pupil: a clear disk of radius c R, then an annulus of height h (phase phi = 2 pi (n - 1) h / lambda).
    At focus the on-axis amplitude is the pupil's area-weighted mean phasor, so against the bare lens

        I(0) / I_lens(0) = | c^2 + (1 - c^2) exp(i phi) |^2.

    A fresh MLP has the constant height h_2pi / 2 (its last layer starts at zero): phi = pi at the design
    wavelength, and with c^2 = 1/2 the focus goes dark there."""
    core = 1 / math.sqrt(2)
    doe = RadialMLPDOE(R, design_wavelength_m=550e-9, levels=16, clear_core_fraction=core)
    wavelengths = [450e-9, 550e-9, 640e-9]
    engine = RadialPSFEngine(GEO, wavelengths, window=9, pupil_samples=1024)
    focus = [GEO.focus_distance_m]
    with torch.no_grad():
        on_axis = engine.radial_intensity(doe, focus)[:, 0, 0]
        lens = engine.radial_intensity(None, focus)[:, 0, 0]
    h = doe.h2pi_m / 2
    for k, lam in enumerate(wavelengths):
        phi = 2 * math.pi * (float(refractive_index(lam, "fused_silica")) - 1) * h / lam
        expected = abs(core**2 + (1 - core**2) * complex(math.cos(phi), math.sin(phi))) ** 2
        assert float(on_axis[k] / lens[k]) == pytest.approx(expected, abs=1e-4), lam
    assert float(on_axis[1] / lens[1]) < 1e-6  # dark at the design wavelength


def test_the_config_takes_a_core_for_the_learned_kinds_only():
    cfg = Config()
    cfg.doe.kind, cfg.doe.clear_core_fraction = "mlp", 0.5
    cfg.doe.validate()
    assert build_doe(cfg).clear_core_radius_m == pytest.approx(0.5 * R)
    cfg.doe.clear_core_fraction = 1.0
    with pytest.raises(ConfigError, match=r"clear_core_fraction=1.0 must lie in \[0, 1\)"):
        cfg.doe.validate()
    cfg.doe.kind, cfg.doe.clear_core_fraction = "cubic", 0.5
    with pytest.raises(ConfigError, match="learned radial kinds"):
        cfg.doe.validate()
