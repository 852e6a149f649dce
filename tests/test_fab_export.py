"""export-doe: GDSII / PNG / CSV round trips, report, all-or-nothing output and CLI errors."""

import json

import numpy as np
import pytest

from edofproj.cli import main
from edofproj.doe import save_doe
from edofproj.doe.storage import TabulatedRadialDOE
from edofproj.errors import EdofprojError
from edofproj.fabrication import export as export_module
from edofproj.fabrication.export import export_doe
from edofproj.fabrication.gdsii import APERTURE_LAYER, inside_layer, read_layers
from edofproj.fabrication.layout import DIE_LAYER
from edofproj.fabrication.masks import level_from_etched
from edofproj.fabrication.profile import RadialProfile
from edofproj.fabrication.raster import read_grey_png
from edofproj.optics.materials import height_2pi_m

R = 3.5e-3
H2PI = height_2pi_m(550e-9)  # 1195.9 nm in fused silica
RINGS = 64


@pytest.fixture()
def design(tmp_path):
    """A 16-level design with 64 rings of random level (every level, many single-ring zones)."""
    level = np.random.default_rng(1).integers(0, 16, RINGS)
    level[:16] = np.arange(16)
    doe = TabulatedRadialDOE(np.linspace(0, R, RINGS + 1), level * H2PI / 16, R, 550e-9, 16)
    path = tmp_path / "design.npz"
    save_doe(doe, path, samples=2 * RINGS)
    return path


def test_gdsii_round_trip_rebuilds_the_profile(design, tmp_path):
    report = export_doe(design, tmp_path / "out")
    profile = RadialProfile.from_file(design)
    layers = read_layers(tmp_path / "out" / "masks.gds")
    assert set(layers) == {1, 2, 3, 4, APERTURE_LAYER, DIE_LAYER}

    def annuli(polygons):  # the optical zones (the alignment marks lie outside the aperture)
        return [p for p in polygons if np.hypot(*p.points.T).max() <= R * 1e6 * (1 + 1e-6)]

    assert [len(annuli(layers[j + 1])) for j in range(4)] == [m["rings"] for m in report["masks"]]
    rng = np.random.default_rng(0)
    for _ in range(3):  # ring centres along random directions
        r_um = profile.ring_centres_m * 1e6
        theta = rng.uniform(0.05, 2 * np.pi - 0.05, len(r_um))
        points = np.stack([r_um * np.cos(theta), r_um * np.sin(theta)], axis=1)
        etched = np.stack([inside_layer(points, layers[j + 1]) for j in range(4)])
        np.testing.assert_array_equal(level_from_etched(etched, 16), profile.level)
        assert inside_layer(points, layers[APERTURE_LAYER]).all()
    outside = np.array([[R * 1e6 * 1.001, 0.0], [0.0, -R * 1e6 * 1.01]])
    assert not inside_layer(outside, layers[APERTURE_LAYER]).any()


def test_gdsii_arcs_stay_within_the_tolerance(design, tmp_path):
    report = export_doe(design, tmp_path / "out")
    tol_um = report["gds"]["tolerance_um"]
    assert tol_um <= 0.01
    edges_um = RadialProfile.from_file(design).ring_edges_m * 1e6
    worst = 0.0
    for polygon in read_layers(tmp_path / "out" / "masks.gds")[1]:
        p = polygon.points
        if np.hypot(*p.T).max() > R * 1e6 * (1 + 1e-6):
            continue  # an alignment mark (outside the aperture), not a ring
        q = np.roll(p, -1, axis=0)
        ra, rb = np.hypot(*p.T), np.hypot(*q.T)
        on_arc = np.abs(ra - rb) < 0.002  # skip the radial cut of a ring polygon
        r_mid = np.hypot(*((p + q)[on_arc] / 2).T)
        radius = edges_um[np.argmin(np.abs(edges_um[None, :] - ra[on_arc][:, None]), axis=1)]
        assert np.all(np.abs(ra[on_arc] - radius) < 0.002)  # vertices on the circle (1 nm grid)
        worst = max(worst, float(np.max(radius - r_mid)))
    assert 0 < worst <= tol_um + 0.002


def test_height_png_and_csv_round_trip(design, tmp_path):
    export_doe(design, tmp_path / "out", map_px=600)
    profile = RadialProfile.from_file(design)
    grey = read_grey_png(tmp_path / "out" / "height_map.png")
    assert grey.dtype == np.uint16 and grey.shape == (600, 600)
    pitch = 2 * R / 600
    c = (np.arange(600) - 300 + 0.5) * pitch
    r = np.hypot(c[:, None], c[None, :])
    ring = np.floor(r / (R / RINGS)).astype(int)  # equal rings: an independent lookup
    inside = r < R
    np.testing.assert_array_equal(grey[inside], profile.level[ring[inside]] * 4096)
    assert np.all(grey[~inside] == 0)
    # CSV: one row per zone, outer radius; rebuild the level of every ring
    table = np.genfromtxt(tmp_path / "out" / "profile.csv", delimiter=",", names=True)
    outer_m = table["radius_um"] * 1e-6
    assert outer_m[-1] == pytest.approx(R)
    zone = np.searchsorted(outer_m, profile.ring_centres_m)
    np.testing.assert_array_equal(table["level"][zone].astype(int), profile.level)
    np.testing.assert_allclose(table["height_nm"], table["level"] * H2PI * 1e9 / 16, atol=1e-4)


def test_report_contents(design, tmp_path):
    report = export_doe(design, tmp_path / "out", critical_dimension_um=60.0)
    on_disk = json.loads((tmp_path / "out" / "fab_report.json").read_text())
    assert on_disk["masks"] == report["masks"]
    assert report["levels"] == 16 and report["masks_count"] == 4
    assert report["total_etch_depth_nm"] == pytest.approx(15 * report["h2pi_nm"] / 16)
    assert report["efficiency"]["design_wavelength"] == pytest.approx(np.sinc(1 / 16) ** 2)
    # single 54.7 um rings exist on mask 0: below a 60 um critical dimension
    assert report["masks"][0]["narrowest_feature_um"] == pytest.approx(R * 1e6 / RINGS, rel=1e-9)
    assert report["masks"][0]["features_below_cd"] > 0
    assert report["passes_critical_dimension"] is False
    md = (tmp_path / "out" / "fab_report.md").read_text()
    assert "FAILS" in md and "98.7 %" in md
    for name in (
        "masks.gds",
        "height_map.png",
        "profile.csv",
        "efficiency.png",
        "mask_0_etch_75nm.png",
        "mask_3_etch_598nm.png",
    ):
        assert (tmp_path / "out" / name).is_file()


def test_two_levels_report_binary_efficiency(design, tmp_path):
    report = export_doe(design, tmp_path / "out", levels=2)
    assert report["masks_count"] == 1 and report["source_levels"] == 16
    assert report["efficiency"]["design_wavelength"] == pytest.approx(0.405, abs=5e-4)


def test_failed_export_leaves_nothing_behind(design, tmp_path, monkeypatch):
    def broken_write_gds(path, *args, **kwargs):
        path.write_bytes(b"partial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(export_module, "write_gds", broken_write_gds)
    with pytest.raises(RuntimeError):
        export_doe(design, tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["design.npz"]


def test_previous_export_is_replaced_and_foreign_directories_refused(design, tmp_path):
    export_doe(design, tmp_path / "out")
    export_doe(design, tmp_path / "out", levels=4)
    assert not (tmp_path / "out" / "mask_3_etch_598nm.png").exists()  # stale 16-level files gone
    assert json.loads((tmp_path / "out" / "fab_report.json").read_text())["levels"] == 4
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert main(["export-doe", str(design), "--out", str(foreign)]) == 2
    assert (foreign / "notes.txt").read_text() == "keep me"


def test_cli_success_and_strict(design, tmp_path, capsys):
    assert main(["export-doe", str(design), "--out", str(tmp_path / "ok")]) == 0
    assert "passes the 1 um critical dimension" in capsys.readouterr().out
    assert (
        main(
            ["export-doe", str(design), "--out", str(tmp_path / "strict"), "--strict", "--critical-dimension-um", "60"]
        )
        == 3
    )
    err = capsys.readouterr().err.strip()
    assert err.startswith("edofproj: error: ") and "below the critical dimension 60 um" in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "strict").exists()
    assert (
        main(
            ["export-doe", str(design), "--out", str(tmp_path / "strict"), "--strict", "--critical-dimension-um", "50"]
        )
        == 0
    )


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--levels", "12"], "levels=12 is not a power of two"),
        # steps below the etch resolution: masks of 0.0 nm and an efficiency near 100 % of a DOE no one can make
        (["--levels", "2048"], "2048 levels make steps of 0.584 nm (h_2pi 1195.9 nm / 2048), the etch depth"),
        (["--levels", "1048576"], "below the 1 nm an etch can control; at most 1024 levels"),
        (["--critical-dimension-um", "0"], "must be > 0"),
        (["--critical-dimension-um", "-1"], "must be > 0"),
        (["--set", "fabrication.critical_dimension_um=0"], "critical_dimension_um=0"),
    ],
)
def test_cli_bad_options(design, tmp_path, capsys, extra, message):
    assert main(["export-doe", str(design), "--out", str(tmp_path / "out")] + extra) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err
    assert not (tmp_path / "out").exists()


def test_cli_bad_inputs(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    assert main(["export-doe", str(run), "--out", str(tmp_path / "out")]) == 2
    assert "has no doe.npz" in capsys.readouterr().err
    odd = tmp_path / "odd.npz"
    save_doe(TabulatedRadialDOE(np.linspace(0, R, 5), np.zeros(4), R, 550e-9, 12), odd, samples=8)
    assert main(["export-doe", str(odd), "--out", str(tmp_path / "out")]) == 2
    assert "not a power of two" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_step_of_the_shallowest_mask_is_checked_against_the_etch_resolution():
    from edofproj.fabrication.profile import MIN_STEP_NM, check_step

    assert check_step(1024, 1196e-9) == pytest.approx(1196e-9 / 1024)
    with pytest.raises(EdofprojError, match="at most 1024 levels"):
        check_step(2048, 1196e-9)
    assert MIN_STEP_NM == 1.0
