"""The manufacturability report of a mask set: features against the critical dimension,
etch depths and diffraction efficiency (``fab_report.json`` + ``fab_report.md``).

Per mask: number of etched annuli (rings), the narrowest feature (an etched ring or the
un-etched gap between two; a central disk counts with its diameter), where it is, and how
many features are narrower than the critical dimension (CD). A design passes when no
feature of any mask is below the CD.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import EdofprojError
from .efficiency import (
    channel_efficiency,
    continuous_efficiency,
    efficiency_spectrum,
    fine_spectrum,
    multilevel_efficiency,
    phase_depth_ratio,
)
from .masks import MaskLayer, top_surface_m
from .profile import RadialProfile

CHANNELS = ("red", "green", "blue")


class CriticalDimensionError(EdofprojError):
    """A feature is narrower than the critical dimension (``export-doe --strict``: exit code 3)."""

    exit_code = 3


@dataclass(frozen=True)
class MaskCheck:
    """Feature statistics of one mask."""

    mask: MaskLayer
    narrowest_um: float | None  # None: the mask etches nothing
    narrowest_at_um: float | None
    narrowest_kind: str
    below_cd: int

    def as_dict(self, etch_error_pct: float = 0.0) -> dict:
        """The mask's entry of ``fab_report.json``: index, GDS layer, etch depth (nm) and its tolerance
        (``etch_error_pct`` of it, 1 sigma, nm), ring count, the narrowest feature's width (um), kind and
        radius of its centre (um; both None when the mask etches nothing), and the number of features below the CD."""
        return {
            "mask": self.mask.index,
            "gds_layer": self.mask.gds_layer,
            "etch_depth_nm": self.mask.etch_depth_m * 1e9,
            "etch_depth_tolerance_nm": self.mask.etch_depth_m * 1e9 * etch_error_pct / 100,
            "rings": self.mask.ring_count,
            "narrowest_feature_um": self.narrowest_um,
            "narrowest_feature_kind": self.narrowest_kind,
            "narrowest_feature_at_radius_um": self.narrowest_at_um,
            "features_below_cd": self.below_cd,
        }


def check_mask(mask: MaskLayer, critical_dimension_m: float) -> MaskCheck:
    """Narrowest feature of a mask and the number of features below the critical dimension."""
    features = mask.features()
    if not features:
        return MaskCheck(mask, None, None, "none", 0)
    widths = np.array([f.width_m for f in features])
    worst = features[int(np.argmin(widths))]
    return MaskCheck(
        mask=mask,
        narrowest_um=float(widths.min() * 1e6),
        narrowest_at_um=float(0.5 * (worst.inner_m + worst.outer_m) * 1e6),
        narrowest_kind=("etched " if worst.etched else "un-etched ") + ("disk" if worst.inner_m == 0.0 else "ring"),
        below_cd=int(np.sum(widths < critical_dimension_m * (1 - 1e-9))),
    )


def check_masks(masks: list[MaskLayer], critical_dimension_m: float) -> list[MaskCheck]:
    """:func:`check_mask` of every mask, in order. Raises :class:`~edofproj.errors.EdofprojError` unless the
    critical dimension (m) is > 0."""
    if not critical_dimension_m > 0:
        raise EdofprojError(f"critical dimension {critical_dimension_m * 1e6:g} um must be > 0")
    return [check_mask(m, critical_dimension_m) for m in masks]


def _narrowest_um(check: MaskCheck) -> float:
    if check.narrowest_um is None:  # below_cd > 0 implies a narrowest feature
        raise EdofprojError(f"mask {check.mask.index} has features below the CD but no narrowest feature")
    return check.narrowest_um


def strict_failure_message(checks: list[MaskCheck], critical_dimension_um: float) -> str | None:
    """One line naming the worst violation, or None when every feature meets the CD."""
    bad = [c for c in checks if c.below_cd]  # below_cd > 0 implies a finite narrowest feature
    if not bad:
        return None
    worst = min(bad, key=_narrowest_um)
    total = sum(c.below_cd for c in bad)
    return (
        f"{total} feature(s) below the critical dimension {critical_dimension_um:g} um; narrowest: "
        f"{worst.narrowest_kind} {worst.narrowest_um:.4g} um wide at r = {worst.narrowest_at_um:.1f} um on mask "
        f"{worst.mask.index} (GDS layer {worst.mask.gds_layer}); export without --strict for the full report"
    )


def build_report(
    profile: RadialProfile,
    masks: list[MaskLayer],
    critical_dimension_um: float,
    spectrum_cfg,
    source: str,
    source_levels: int | None,
    files: dict | None = None,
    layout=None,
    etch_error_pct: float = 0.0,
) -> dict:
    """The report as a JSON-ready mapping; ``layout`` (:class:`~.layout.DieLayout`): the die, marks, substrate and
    mask tones; ``etch_error_pct``: the etch-depth tolerance of each step (1 sigma, percent of its depth)."""
    checks = check_masks(masks, critical_dimension_um * 1e-6)
    edges, _ = profile.zones()
    lam_d = profile.design_wavelength_m
    spectrum = fine_spectrum(spectrum_cfg)
    per_channel = channel_efficiency(profile.levels, spectrum, lam_d, profile.material)
    table_nm = np.arange(400.0, 701.0, 10.0)
    eta_table = efficiency_spectrum(profile.levels, table_nm * 1e-9, lam_d, profile.material)
    return {
        "source": source,
        "description": profile.description,
        "levels": profile.levels,
        "source_levels": source_levels,
        "masks_count": len(masks),
        "design_wavelength_nm": lam_d * 1e9,
        "material": profile.material,
        "h2pi_nm": profile.h2pi_m * 1e9,
        "step_nm": profile.step_m * 1e9,
        "aperture_radius_um": profile.aperture_radius_m * 1e6,
        "design_rings": int(len(profile.level)),
        "zones": int(len(edges) - 1),
        "narrowest_zone_um": profile.narrowest_zone_m() * 1e6,
        "etch_convention": "height = level * step above the deepest etch floor; etched depth = (N-1-level) * step; "
        "mask j (GDS layer j+1) etches step*2^j where bit j of (N-1-level) is set",
        "total_etch_depth_nm": top_surface_m(profile) * 1e9,
        "critical_dimension_um": critical_dimension_um,
        "etch_depth_tolerance_pct": etch_error_pct,
        "masks": [c.as_dict(etch_error_pct) for c in checks],
        "die": layout.as_dict(profile.material) if layout is not None else None,
        "passes_critical_dimension": not any(c.below_cd for c in checks),
        "efficiency": {
            "formula": "eta_1 = sinc^2(1/N) [sinc(alpha-1)/sinc((alpha-1)/N)]^2, "
            "alpha = (n(lambda)-1) lambda_d / ((n(lambda_d)-1) lambda)",
            "design_wavelength": float(multilevel_efficiency(profile.levels)),
            "per_channel_spd_weighted": {name: float(v) for name, v in zip(CHANNELS, per_channel)},
            "continuous_profile_per_channel": {
                name: float(v)
                for name, v in zip(
                    CHANNELS,
                    spectrum.weights
                    @ continuous_efficiency(phase_depth_ratio(spectrum.wavelengths_m, lam_d, profile.material)),
                )
            },
            "wavelength_nm": table_nm.tolist(),
            "eta": eta_table.tolist(),
        },
        "files": files or {},
    }


def clean_room_lines(report: dict) -> list[str]:
    """The report's section for the clean room: substrate, die, resist and mask tone, alignment marks, and the
    etch steps in the order they are run with their depths and tolerances (empty without a die layout)."""
    die = report.get("die")
    if not die:
        return []
    sub, marks = die["substrate"], die["alignment_marks"]
    tol = report.get("etch_depth_tolerance_pct", 0.0)
    sites = ", ".join(f"({x:.0f}, {y:.0f})" for x, y in marks["sites_um"])
    lines = [
        "## For the clean room",
        "",
        f"* Substrate: {str(sub['material']).replace('_', ' ')} wafer, {sub['diameter_mm']:g} mm diameter x {sub['thickness_mm']:g} mm thick, "
        f"{sub['edge_exclusion_mm']:g} mm edge exclusion: {sub['dies']} dies.",
        f"* Die: {die['die_mm']:g} x {die['die_mm']:g} mm, centred on the optical axis; outline (dicing line) on GDS "
        f"layer {die['die_gds_layer']}.",
        f"* Resist: {die['resist']}. Etch masks (GDS layers 1-{report['masks_count']}): "
        f"**{die['etch_mask_tone']['field']}**, polygons = {die['etch_mask_tone']['polygons']}. Aperture mask "
        f"(layer 100): **{die['aperture_mask_tone']['field']}**, polygons = {die['aperture_mask_tone']['polygons']}.",
        f"* Alignment marks on every layer at {sites} um: crosses {marks['cross_length_um']:g} um long, "
        f"{marks['cross_width_um']:g} um wide; {marks['scheme']} ({marks['frame_gap_um']:g} um nominal gap).",
        "",
        "| step | mask (GDS layer) | etch depth (nm) | tolerance, 1 sigma (nm) |",
        "| --- | --- | --- | --- |",
    ]
    for step, m in enumerate(report["masks"], start=1):
        lines.append(
            f"| {step} | {m['mask']} ({m['gds_layer']}) | {m['etch_depth_nm']:.1f} | "
            f"+-{m.get('etch_depth_tolerance_nm', 0.0):.1f} ({tol:g} %) |"
        )
    lines += [
        f"| {len(report['masks']) + 1} | aperture (100) | chrome stop outside the aperture | - |",
        "",
        f"Total etch depth {report['total_etch_depth_nm']:.1f} nm. The tolerances are fabrication.etch_error_pct; "
        "`edofproj tolerance` simulates what they (and the overlay error) do to the PSFs.",
        "",
    ]
    return lines


def report_markdown(report: dict) -> str:
    """Human-readable version of :func:`build_report`."""
    cd = report["critical_dimension_um"]
    verdict = "PASSES" if report["passes_critical_dimension"] else "FAILS"
    eff = report["efficiency"]
    lines = [
        "# DOE fabrication report",
        "",
        f"Source: `{report['source']}` ({report['description']})",
        "",
        f"* Levels: {report['levels']} ({report['masks_count']} masks)"
        + (
            f", re-quantized from {report['source_levels']}"
            if report["source_levels"] not in (None, report["levels"])
            else ""
        ),
        f"* Design wavelength {report['design_wavelength_nm']:.1f} nm, {report['material']}: "
        f"h2pi = {report['h2pi_nm']:.1f} nm, step = {report['step_nm']:.2f} nm",
        f"* Aperture radius {report['aperture_radius_um']:.1f} um; {report['design_rings']} design rings merged into "
        f"{report['zones']} constant-level zones (narrowest {report['narrowest_zone_um']:.3g} um)",
        f"* Etch convention: {report['etch_convention']}",
        f"* Total etch depth: {report['total_etch_depth_nm']:.1f} nm",
        "",
    ]
    lines += clean_room_lines(report)
    lines += [
        f"## Masks against the critical dimension ({cd:g} um): {verdict}",
        "",
        "| mask | GDS layer | etch depth (nm) | tolerance, 1 sigma (nm) | rings | narrowest feature (um) | kind | "
        "at radius (um) | below CD |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for m in report["masks"]:
        width, at = m["narrowest_feature_um"], m["narrowest_feature_at_radius_um"]
        lines.append(
            f"| {m['mask']} | {m['gds_layer']} | {m['etch_depth_nm']:.1f} | "
            f"+-{m.get('etch_depth_tolerance_nm', 0.0):.1f} | {m['rings']} | "
            f"{'-' if width is None else f'{width:.4g}'} | {m['narrowest_feature_kind']} | "
            f"{'-' if at is None else f'{at:.1f}'} | {m['features_below_cd']} |"
        )
    lines += [
        "",
        "## Scalar diffraction efficiency (first order)",
        "",
        f"{eff['formula']}.",
        "",
        f"* At the design wavelength: sinc^2(1/N) = {100 * eff['design_wavelength']:.1f} %",
        "* SPD-weighted per primary (SPDs resampled at 1 nm): "
        + ", ".join(f"{k} {100 * v:.1f} %" for k, v in eff["per_channel_spd_weighted"].items())
        + " (continuous profile: "
        + ", ".join(f"{k} {100 * v:.1f} %" for k, v in eff["continuous_profile_per_channel"].items())
        + ")",
        "",
        "| wavelength (nm) | " + " | ".join(f"{w:.0f}" for w in eff["wavelength_nm"][::3]) + " |",
        "| --- | " + " | ".join("---" for _ in eff["wavelength_nm"][::3]) + " |",
        "| eta (%) | " + " | ".join(f"{100 * e:.1f}" for e in eff["eta"][::3]) + " |",
        "",
        "The light missing from the first order goes to other diffraction orders (haze). The PSF",
        "simulation of the design already includes the quantized profile and the dispersion; these",
        "figures are the textbook estimate for locally periodic zones.",
    ]
    if report.get("gds"):
        gds = report["gds"]
        lines += [
            "",
            f"GDSII: {gds['polygons']} polygons, {gds['vertices']} vertices, arc sagitta <= "
            f"{gds['tolerance_um']:g} um.",
        ]
    if report.get("files"):
        lines += ["", "## Files", ""]
        lines += [f"* `{name}`: {what}" for name, what in report["files"].items()]
    return "\n".join(lines) + "\n"
