"""Sampling advice: every requirement at once, and following the message once is enough (optics/sampling.py)."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from edofproj.doe.designs import Axicon
from edofproj.doe.mlp import RadialMLPDOE
from edofproj.errors import SamplingError
from edofproj.optics.aberrations import PupilAberration
from edofproj.optics.fourier_engine import FourierPSFEngine
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_checks import validate_psf
from edofproj.optics.radial_engine import RadialPSFEngine

GEO = ProjectorGeometry()
R = GEO.aperture_radius_m


def follow_once(engine_cls, window, depths_m, doe=None, aberration=None, start=64):
    """The message at ``start`` samples, and the PSF at the sampling it names (which must pass every check)."""
    with pytest.raises(SamplingError) as refused:
        engine_cls(GEO, [460e-9, 620e-9], window, start, aberration=aberration).psf(doe, depths_m)
    message = str(refused.value)
    named = int(re.search(r"use pupil_samples >= (\d+)", message).group(1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the blur may exceed the window: that light is haze
        psf = engine_cls(GEO, [460e-9, 620e-9], window, named, aberration=aberration).psf(doe, depths_m)
    validate_psf(psf, depths_m, source="the PSF", measured=False, fix="")
    return message, named, psf


@pytest.mark.parametrize(
    ("depths_m", "expected"),
    [([0.3, 0.8], 286), ([0.2, 0.8], 640)],  # 2 pi R (D / M) |1/z - 1/v| / 460 nm <= pi / 2
)
def test_the_radial_engine_names_the_defocus_sampling_and_its_psf_then_passes_the_energy_check(depths_m, expected):
    message, named, psf = follow_once(RadialPSFEngine, 33, depths_m)
    assert named == expected and "defocus" in message
    assert float(psf.sum(dim=(-1, -2)).max()) <= 1.0  # the energy check that failed after the advice before


def test_the_2d_engine_names_one_sampling_for_the_defocus_and_the_field_of_view_together():
    message, named, _ = follow_once(FourierPSFEngine, 33, [0.3, 0.8])
    assert "defocus" in message and "field of view" in message
    # the field of view lambda T W M / D must hold 33 px + the 11.2-px blur at 300 mm
    blur = float(GEO.blur_diameter_px(0.3))
    assert named == 2 * int(np.ceil((33 + blur) * GEO.aperture_diameter_m / (460e-9 * GEO.throw_width_m) / 2))


def test_a_design_rule_and_the_defocus_are_named_together_with_the_designs_other_fix():
    doe = RadialMLPDOE(R, frequencies=9)  # its encoding needs 1024 samples
    message, named, _ = follow_once(RadialPSFEngine, 9, [0.2], doe=doe)
    assert named == 1024 and "defocus" in message and "doe.mlp_frequencies" in message


@pytest.mark.parametrize(
    ("engine_cls", "aberration", "doe"),
    [
        (RadialPSFEngine, PupilAberration.from_zernike_um({11: 3.0}), None),
        (FourierPSFEngine, PupilAberration.from_zernike_um({6: 2.0}), None),
        (FourierPSFEngine, PupilAberration.from_zernike_um({11: 1.0}), Axicon(R, 550e-9)),
    ],
)
def test_following_the_message_once_is_enough_with_aberrations_and_designs(engine_cls, aberration, doe):
    message, named, _ = follow_once(engine_cls, 15, [0.45, 0.55], doe=doe, aberration=aberration)
    assert "aberration" in message and named > 64
