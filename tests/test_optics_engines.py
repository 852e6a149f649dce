"""Radial vs 2-D engine, convergence in pupil sampling, sampling refusals, gradients."""

import pytest
import torch

from edofproj.doe.designs import Multifocal
from edofproj.doe.mlp import RadialMLPDOE
from edofproj.doe.storage import load_doe, save_doe
from edofproj.errors import SamplingError
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.radial_engine import RadialPSFEngine

DEPTHS = [0.3, 0.5, 0.8]


def l1(a, b):
    """L1 difference as a fraction of the pupil energy, per PSF."""
    return (a - b).abs().sum(dim=(-1, -2))


@pytest.mark.parametrize("design", ["lens", "multifocal"])
def test_radial_and_2d_engines_agree(geometry, design):
    doe = None if design == "lens" else Multifocal(geometry.aperture_radius_m, foci_m=(0.4, 0.65))
    # the quantized DOE's level edges are snapped to rings in one engine and point-sampled on a
    # square grid in the other: 1536 samples resolve them well enough (1024: up to 1.3 % L1 at 450 nm)
    samples = 1024 if design == "lens" else 1536
    radial = RadialPSFEngine(geometry, [450e-9, 650e-9], window=21, pupil_samples=samples)
    fourier = FourierPSFEngine(geometry, [450e-9, 650e-9], window=21, pupil_samples=samples)
    with torch.no_grad():
        a, b = radial.psf(doe, DEPTHS), fourier.psf(doe, DEPTHS)
    assert float(l1(a, b).max()) < 0.01


def test_doubling_pupil_samples_changes_psf_by_less_than_half_a_percent(geometry, tmp_path):
    torch.manual_seed(1)
    mlp = RadialMLPDOE(geometry.aperture_radius_m, frequencies=6, hidden=16, layers=2)
    for p in mlp.parameters():
        torch.nn.init.normal_(p, std=0.5)
    # freeze the design as fabricated on 512 rings, so both samplings see the same element
    save_doe(mlp, tmp_path / "doe.npz", samples=1024)
    doe = load_doe(tmp_path / "doe.npz")
    for d in (None, doe):
        coarse = RadialPSFEngine(geometry, [450e-9, 650e-9], window=21, pupil_samples=1024).psf(d, DEPTHS)
        fine = RadialPSFEngine(geometry, [450e-9, 650e-9], window=21, pupil_samples=2048).psf(d, DEPTHS)
        assert float(l1(coarse, fine).max()) < 0.005


def test_float32_matches_float64(geometry):
    doe = Multifocal(geometry.aperture_radius_m)
    a = RadialPSFEngine(geometry, [550e-9], 15, 512, dtype=torch.float64).psf(doe, DEPTHS)
    b = RadialPSFEngine(geometry, [550e-9], 15, 512, dtype=torch.float32).psf(doe, DEPTHS)
    assert float(l1(a, b.double()).max()) < 1e-4


def test_radial_engine_refuses_unresolved_defocus(geometry):
    engine = RadialPSFEngine(geometry, [400e-9], window=9, pupil_samples=64)
    with pytest.raises(SamplingError, match="pupil_samples >= "):
        engine.psf(None, [0.3])


def test_2d_engine_refuses_a_field_of_view_that_would_alias(geometry):
    with pytest.raises(SamplingError, match="pupil_samples"):
        FourierPSFEngine(geometry, [550e-9], window=41, pupil_samples=512).psf(None, [0.3])


def test_mlp_encoding_finer_than_the_pupil_sampling_is_refused(geometry):
    doe = RadialMLPDOE(geometry.aperture_radius_m, frequencies=9)
    engine = RadialPSFEngine(geometry, [550e-9], window=9, pupil_samples=256)
    with pytest.raises(SamplingError, match="mlp_frequencies"):
        engine.psf(doe, [0.5])


class _PSFOf(torch.nn.Module):
    """PSFs as a module of the DOE's parameters (so torch.func can substitute them)."""

    def __init__(self, doe, engine):
        super().__init__()
        self.doe, self.engine = doe, engine

    def forward(self, depths_m):
        return self.engine.psf(self.doe, depths_m)


def test_gradcheck_through_the_radial_engine_wrt_mlp_parameters(geometry):
    torch.manual_seed(0)
    # gradcheck needs a smooth map: quantization (a straight-through step) is off here
    doe = RadialMLPDOE(geometry.aperture_radius_m, levels=None, frequencies=2, hidden=3, layers=1).double()
    for p in doe.parameters():
        torch.nn.init.normal_(p, std=0.3)
    engine = RadialPSFEngine(geometry, [550e-9], window=5, pupil_samples=64, dtype=torch.float64)
    module = _PSFOf(doe, engine)
    names = [f"doe.{n}" for n, _ in doe.named_parameters()]
    inputs = tuple(p.detach().clone().requires_grad_(True) for p in doe.parameters())

    def psf_of(*values):
        return torch.func.functional_call(module, dict(zip(names, values)), ([0.45, 0.55],))

    assert torch.autograd.gradcheck(psf_of, inputs, eps=1e-6, atol=1e-7, rtol=1e-4)
