"""Ranges from the run (issue 57): the tilted screen, the tolerance headline and the summary use the run's
scored range, a ``base`` config of another projector does not inherit the base's ranges, and the design
wavelength follows the primaries unless set."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from edofproj.config import load_config

PICO = """base: cpu
optics:
  aperture_mm: 5.0
  throw_ratio: 1.2
  focus_mm: 1200.0
  width_px: 1920
  height_px: 1080
spectrum:
  peaks_nm: [625.0, 525.0, 455.0]
psf:
  depth_min_mm: 780.0
  depth_max_mm: 2500.0
"""


@pytest.fixture
def pico(tmp_path):
    path = tmp_path / "pico.yaml"
    path.write_text(PICO)
    return path


def test_the_tilted_screen_spans_the_scored_range(pico):
    from edofproj.evaluation.sweep import TiltedScreen

    cfg = load_config(str(pico), ["evaluation.score_range_mm=[800,2500]"])
    screen = TiltedScreen(cfg, 8, 16)
    assert (screen.near_m, screen.far_m) == pytest.approx((0.8, 2.5))
    # the depth map runs from near (left) to far (right), 1/z affine across the columns (closed form)
    inv = 1.0 / screen.depth_map_m[0]
    assert inv[0] == pytest.approx(1 / 0.8, rel=0.05) and inv[-1] == pytest.approx(1 / 2.5, rel=0.05)
    assert np.allclose(np.diff(inv, 2), 0.0, atol=1e-9)
    # no scored range: the training range; a tilted range of its own: that one
    assert TiltedScreen(load_config(str(pico)), 8, 16).near_m == pytest.approx(0.78)
    own = load_config(str(pico), ["evaluation.tilt_range_mm=[1000,1500]"])
    assert (TiltedScreen(own, 8, 16).near_m, TiltedScreen(own, 8, 16).far_m) == pytest.approx((1.0, 1.5))


def test_the_presets_keep_the_papers_tilted_screen_and_old_runs_read_as_before(tmp_path):
    from edofproj.config import dump_config

    assert load_config("cpu").evaluation.tilt_range_mm == [500.0, 700.0]  # v to v + 200 mm (paper Sec. 5.3)
    old = dump_config(load_config("cpu", ["optics.focus_mm=600"])).replace(
        "tilt_range_mm:\n  - 500.0\n  - 700.0\n", "tilt_span_mm: 150.0\n"
    )
    assert "tilt_span_mm: 150.0" in old
    path = tmp_path / "config.yaml"
    path.write_text(old)
    assert load_config(str(path)).evaluation.tilt_range_mm == [600.0, 750.0]


def test_a_base_config_of_another_projector_does_not_inherit_its_ranges(pico):
    cpu = load_config("cpu")
    cfg = load_config(str(pico))
    assert cpu.evaluation.score_range_mm == [300.0, 800.0] and cfg.evaluation.score_range_mm == []
    assert cfg.evaluation.tilt_range_mm == []
    from edofproj.methods.compensators import score_range_mm

    assert score_range_mm(cfg) == (780.0, 2500.0)


def test_the_design_wavelength_follows_the_primaries_unless_set(pico):
    from edofproj.doe import build_doe
    from edofproj.optics.spectra import design_wavelength_nm

    # LED-like Gaussian peaks well inside 400-700 nm: their centroids are the peaks (closed form)
    default = load_config(None)
    assert default.doe.design_wavelength_nm is None
    assert design_wavelength_nm(default) == pytest.approx(np.mean([620.0, 530.0, 460.0]), abs=0.05)
    cfg = load_config(str(pico))  # the cpu preset's 550 nm was set for its primaries, not these
    assert design_wavelength_nm(cfg) == pytest.approx(np.mean([625.0, 525.0, 455.0]), abs=0.05)
    assert build_doe(cfg, "cubic").design_wavelength_m == pytest.approx(design_wavelength_nm(cfg) * 1e-9)
    assert design_wavelength_nm(load_config("cpu")) == 550.0
    assert design_wavelength_nm(load_config(str(pico), ["doe.design_wavelength_nm=532"])) == 532.0


def test_the_tolerance_headline_is_the_worst_depth_of_the_scored_range(pico):
    from edofproj.commands.tolerance import headline_depth_index

    cfg = load_config(str(pico), ["evaluation.score_range_mm=[800,2500]"])
    depths = [800.0, 1200.0, 2500.0, 3000.0]
    p05 = [0.5, 0.7, 0.4, 0.1]  # 3000 mm is the worst, but not scored
    index, span = headline_depth_index(depths, p05, cfg)
    assert depths[index] == 2500.0 and span == (800.0, 2500.0)


def test_the_summary_names_the_training_and_the_scored_range(pico):
    from edofproj.reporting.writeup import overview

    cfg = load_config(str(pico), ["evaluation.score_range_mm=[800,2500]"])
    ev = SimpleNamespace(
        run=SimpleNamespace(run_dir="runs/pico", step=10, doe=SimpleNamespace(describe=lambda: "a DOE")),
        designs={},
        images=[("a", np.zeros((3, 16, 16)))],
        range_mm=(800.0, 2500.0),
        cfg=cfg,
        image_set="held-out",
        depths_mm=[800.0, 2500.0],
    )
    text = overview(ev)[0].text
    assert "training depth range 780-2500 mm" in text and "scored depth range 800-2500 mm" in text
