"""Export a radial DOE design for lithography: profile CSV, height map, masks (GDSII + previews), report.

Output directory (written all-or-nothing, see :mod:`.output_dir`):

* ``profile.csv``: ``radius_um,height_nm,level``, one row per constant-level zone (adjacent
  design rings of equal level merged); ``radius_um`` is the zone's *outer* radius, the zone
  starting at the previous row's radius (the first at the axis);
* ``height_map.png``: 16-bit height map across the aperture (scaling in :mod:`.raster`);
* ``masks.gds``: mask j on GDS layer j + 1, the clear aperture on layer 100 (:mod:`.gdsii`), alignment
  marks on every layer and the die outline on layer 101 (:mod:`.layout`);
* ``mask_<j>_etch_<depth>nm.png``: previews of each mask (white = etched);
* ``efficiency.png``: first-order efficiency against wavelength, with the primaries' SPDs;
* ``fab_report.json`` / ``fab_report.md``: the manufacturability report (:mod:`.report`).
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ..config import FabricationConfig, SpectrumConfig  # noqa: E402
from ..doe.storage import load_doe  # noqa: E402
from ..errors import EdofprojError  # noqa: E402
from .efficiency import continuous_efficiency, efficiency_spectrum, fine_spectrum, phase_depth_ratio  # noqa: E402
from .gdsii import arc_tolerance_um as choose_arc_tolerance_um  # noqa: E402
from .gdsii import write_gds
from .layout import DIE_LAYER, DieLayout  # noqa: E402
from .masks import decompose  # noqa: E402
from .output_dir import staged_directory  # noqa: E402
from .profile import RadialProfile  # noqa: E402
from .raster import auto_map_size_px, height_map_grey, mask_preview, png_bytes  # noqa: E402
from .report import CriticalDimensionError, build_report, check_masks, report_markdown, strict_failure_message  # noqa: E402

PROFILE_CSV = "profile.csv"
HEIGHT_PNG = "height_map.png"
GDS_FILE = "masks.gds"
EFFICIENCY_PNG = "efficiency.png"
REPORT_JSON = "fab_report.json"
REPORT_MD = "fab_report.md"


def mask_preview_name(mask) -> str:
    return f"mask_{mask.index}_etch_{mask.etch_depth_m * 1e9:.0f}nm.png"


def profile_csv_text(profile: RadialProfile) -> str:
    """``radius_um,height_nm,level`` per zone (outer radius; see the module docstring)."""
    edges, level = profile.zones()
    rows = ["radius_um,height_nm,level"]
    rows += [f"{r * 1e6:.6f},{lv * profile.step_m * 1e9:.4f},{lv}" for r, lv in zip(edges[1:], level)]
    return "\n".join(rows) + "\n"


def plot_efficiency(path: Path, profile: RadialProfile, spectrum_cfg) -> None:
    """First-order efficiency vs wavelength (N levels and continuous) over the primaries' SPDs."""
    spectrum = fine_spectrum(spectrum_cfg)
    lam = spectrum.wavelengths_m
    alpha = phase_depth_ratio(lam, profile.design_wavelength_m, profile.material)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for weights, colour in zip(spectrum.weights, ("tab:red", "tab:green", "tab:blue")):
        ax.fill_between(lam * 1e9, 0, weights / weights.max() * 30, color=colour, alpha=0.25, lw=0)
    ax.plot(
        lam * 1e9,
        100 * efficiency_spectrum(profile.levels, lam, profile.design_wavelength_m, profile.material),
        "k-",
        label=f"{profile.levels} levels",
    )
    ax.plot(lam * 1e9, 100 * continuous_efficiency(alpha), "k--", lw=1, label="continuous profile")
    ax.axvline(profile.design_wavelength_m * 1e9, color="0.6", lw=0.8)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("first-order efficiency (%)")
    ax.set_ylim(0, 100)
    ax.set_title("Scalar diffraction efficiency (shaded: primaries' SPDs, arbitrary scale)", fontsize=9)
    ax.legend(loc="center right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def export_doe(
    doe_file: str | Path,
    out_dir: str | Path,
    *,
    levels: int | None = None,
    critical_dimension_um: float = 1.0,
    arc_tolerance_um: float = 0.01,
    spectrum_cfg=None,
    strict: bool = False,
    map_px: int | None = None,
    source: str | None = None,
    fabrication_cfg: FabricationConfig | None = None,
) -> dict:
    """Export ``doe_file`` into ``out_dir``; returns the report mapping.

    ``levels``: re-quantize to this many levels (a power of two; default: the design's own).
    ``strict``: raise :class:`~.report.CriticalDimensionError` (and write nothing) if any mask
    feature is narrower than ``critical_dimension_um``. ``fabrication_cfg``: the die, substrate, resist and
    etch-depth tolerance (``etch_error_pct``) of the report and the layout (default: the defaults).
    """
    if not critical_dimension_um > 0:
        raise EdofprojError(f"--critical-dimension-um={critical_dimension_um:g} must be > 0")
    if map_px is not None and not (2 <= map_px <= 16384):
        raise EdofprojError(f"height-map size {map_px} must be in 2-16384 pixels")
    spectrum_cfg = spectrum_cfg or SpectrumConfig()
    fabrication_cfg = fabrication_cfg or FabricationConfig()
    doe = load_doe(doe_file)
    if not doe.radially_symmetric:
        raise EdofprojError(f"'{doe_file}' holds a 2-D height map; mask export needs a radial design")
    profile = RadialProfile.from_doe(doe, levels)
    source_levels = doe.levels
    masks = decompose(profile)
    layout = DieLayout.from_config(fabrication_cfg, profile.aperture_radius_m)
    checks = check_masks(masks, critical_dimension_um * 1e-6)
    if strict:
        message = strict_failure_message(checks, critical_dimension_um)
        if message:
            raise CriticalDimensionError(message)

    narrowest_m = min([profile.narrowest_zone_m()] + [c.narrowest_um * 1e-6 for c in checks if c.narrowest_um])
    tolerance_um = choose_arc_tolerance_um(narrowest_m, arc_tolerance_um)
    size = int(map_px) if map_px else auto_map_size_px(profile)
    pitch_um = 2 * profile.aperture_radius_m * 1e6 / size
    files = {
        PROFILE_CSV: "radius_um,height_nm,level per constant-level zone; radius_um = the zone's outer radius "
        "(it starts at the previous row's radius, the first at 0)",
        HEIGHT_PNG: f"16-bit height map, {size}x{size} px across the aperture ({pitch_um:.3f} um/px); "
        f"grey = level*65536/N (height_nm = grey*h2pi_nm/65536); 0 outside the aperture"
        + (
            ""
            if pitch_um <= profile.narrowest_zone_m() * 1e6 / 2
            else "; this pitch does not resolve the narrowest zone (preview only; the GDSII is exact)"
        ),
        GDS_FILE: f"GDSII (um units, 1 nm grid): mask j on layer j+1 = etched regions and its alignment marks, "
        f"layer 100 = clear aperture and mark windows (chrome outside), layer {DIE_LAYER} = die outline; "
        f"arc sagitta <= {tolerance_um:g} um",
        EFFICIENCY_PNG: "first-order efficiency vs wavelength",
    }
    for mask in masks:
        files[mask_preview_name(mask)] = (
            f"preview of mask {mask.index} (white = etched {mask.etch_depth_m * 1e9:.1f} nm)"
        )
    report = build_report(
        profile,
        masks,
        critical_dimension_um,
        spectrum_cfg,
        source=source or str(doe_file),
        source_levels=source_levels,
        files=files,
        layout=layout,
        etch_error_pct=fabrication_cfg.etch_error_pct,
    )

    with staged_directory(out_dir, REPORT_JSON) as stage:
        (stage / PROFILE_CSV).write_text(profile_csv_text(profile), encoding="utf-8")
        (stage / HEIGHT_PNG).write_bytes(png_bytes(height_map_grey(profile, size)))
        for mask in masks:
            (stage / mask_preview_name(mask)).write_bytes(png_bytes(mask_preview(mask, profile.aperture_radius_m)))
        report["gds"] = write_gds(stage / GDS_FILE, masks, profile.aperture_radius_m, tolerance_um, layout)
        plot_efficiency(stage / EFFICIENCY_PNG, profile, spectrum_cfg)
        (stage / REPORT_MD).write_text(report_markdown(report), encoding="utf-8")
        (stage / REPORT_JSON).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return report
