"""The fabrication report a clean room needs (issue 57): alignment marks on every mask layer of the GDS,
the mask tone, the substrate and die, and each etch step's depth with its tolerance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edofproj.config import Config, FabricationConfig, apply_overrides
from edofproj.doe import build_doe, save_doe
from edofproj.errors import EdofprojError
from edofproj.fabrication.export import export_doe
from edofproj.fabrication.gdsii import APERTURE_LAYER, inside_layer, read_layers
from edofproj.fabrication.layout import (
    CROSS_LENGTH_UM,
    DIE_LAYER,
    FRAME_GAP_UM,
    FRAME_WIDTH_UM,
    DieLayout,
    frame_half_um,
)


@pytest.fixture(scope="module")
def design(tmp_path_factory):
    cfg = apply_overrides(Config(), ["psf.pupil_samples=256", "doe.levels=8", "doe.design_wavelength_nm=550"])
    path = tmp_path_factory.mktemp("design") / "doe.npz"
    save_doe(build_doe(cfg, "multifocal"), path, samples=256)
    return path


@pytest.fixture(scope="module")
def exported(design, tmp_path_factory):
    out = tmp_path_factory.mktemp("fab") / "out"
    report = export_doe(design, out, fabrication_cfg=FabricationConfig(etch_error_pct=2.0))
    return out, report


def test_every_mask_layer_carries_alignment_marks_outside_the_aperture(exported):
    out, report = exported
    layers = read_layers(out / "masks.gds")
    masks = report["masks"]
    assert len(masks) == 3  # 8 levels
    radius_um = report["aperture_radius_um"]
    sites = report["die"]["alignment_marks"]["sites_um"]
    assert len(sites) == 2
    for x, y in sites:
        assert abs(x) - frame_half_um() > radius_um  # the whole mark lies outside the clear aperture
        arm = np.array([[x, y], [x + 0.45 * CROSS_LENGTH_UM, y], [x, y - 0.45 * CROSS_LENGTH_UM]])
        frame = np.array([[x + CROSS_LENGTH_UM / 2 + FRAME_GAP_UM + FRAME_WIDTH_UM / 2, y]])
        gap = np.array([[x + CROSS_LENGTH_UM / 2 + FRAME_GAP_UM / 2, y]])
        for m in masks:
            polygons = layers[m["gds_layer"]]
            assert inside_layer(arm, polygons).all(), m  # the cross, on every mask
            assert inside_layer(frame, polygons)[0] == (m["mask"] > 0)  # the frame on the later masks (box-in-box)
            assert not inside_layer(gap, polygons)[0]
        # the aperture layer opens a window over each mark (the chrome stop must not bury it)
        assert inside_layer(np.array([[x, y], frame[0]]), layers[APERTURE_LAYER]).all()


def test_the_die_outline_and_substrate_are_drawn_and_reported(exported):
    out, report = exported
    die = report["die"]
    outline = read_layers(out / "masks.gds")[DIE_LAYER]
    assert len(outline) == 1
    points = outline[0].points
    side_mm = die["die_mm"]
    assert np.allclose(points.min(axis=0), -side_mm * 500) and np.allclose(points.max(axis=0), side_mm * 500)
    assert side_mm % 0.5 == 0 and side_mm * 500 >= abs(die["alignment_marks"]["sites_um"][0][0]) + frame_half_um()
    assert die["substrate"] == {
        "material": "fused_silica",
        "diameter_mm": 100.0,
        "thickness_mm": 0.5,
        "edge_exclusion_mm": 3.0,
        "dies": die["substrate"]["dies"],
    }
    # bounds in closed form: no more than the usable disk's area holds, no fewer than its inscribed square's grid
    usable_mm, dies = 47.0, die["substrate"]["dies"]
    assert int(usable_mm * np.sqrt(2) // side_mm) ** 2 <= dies <= np.pi * usable_mm**2 / side_mm**2
    text = (out / "fab_report.md").read_text()
    assert "## For the clean room" in text and "dark field" in text and f"{side_mm:g} x {side_mm:g} mm" in text


def test_each_etch_step_has_its_depth_and_tolerance(exported):
    out, report = exported
    step_nm = report["step_nm"]
    for m in report["masks"]:
        assert m["etch_depth_nm"] == pytest.approx(step_nm * 2 ** m["mask"])  # 2^j steps (closed form)
        assert m["etch_depth_tolerance_nm"] == pytest.approx(0.02 * m["etch_depth_nm"])
    on_disk = json.loads((out / "fab_report.json").read_text())
    assert on_disk["etch_depth_tolerance_pct"] == 2.0
    text = (out / "fab_report.md").read_text()
    assert f"+-{0.02 * step_nm:.1f} (2 %)" in text


def test_the_mask_tone_follows_the_resist():
    positive = DieLayout.from_config(FabricationConfig(), 3.5e-3)
    negative = DieLayout.from_config(FabricationConfig(resist="negative"), 3.5e-3)
    assert positive.tone("etch")["field"] == "dark field" and "clear openings" in positive.tone("etch")["polygons"]
    assert negative.tone("etch")["field"] == "clear field" and "chrome" in negative.tone("etch")["polygons"]


def test_dies_per_substrate_and_refusals():
    # one 40 mm die fits a 100 mm wafer with 3 mm exclusion (corner at 28.3 mm < 47 mm), two do not (56.6 mm)
    one = DieLayout.from_config(FabricationConfig(die_mm=40.0), 3.5e-3)
    assert one.dies_per_substrate() == 1
    with pytest.raises(EdofprojError, match="smaller than the aperture and its alignment marks"):
        DieLayout.from_config(FabricationConfig(die_mm=5.0), 3.5e-3)
    with pytest.raises(EdofprojError, match="does not fit"):
        DieLayout.from_config(FabricationConfig(die_mm=40.0, substrate_diameter_mm=50.0), 3.5e-3)
