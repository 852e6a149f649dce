"""Tutorial 3: export a DOE for multi-level lithography and read the manufacturability report.

    python docs/tutorials/export_for_lithography.py --out tutorial_out/fab [--doe RUN_OR_NPZ] [--small]

Exports a radial DOE design (a run directory holding ``doe.npz``, a design ``.npz``, or by default
an axicon with a focal line from 300 to 800 mm) as binary masks at 16 levels, reads
``fab_report.json`` (levels, masks and their etch depths, the narrowest feature against the
critical dimension, the diffraction efficiency), then exports it again at 8, 4 and 2 levels to
show the trade-off between efficiency and feature size, and checks a too-coarse process in strict
mode. The same as ``edofproj export-doe DESIGN --out DIR --levels N --critical-dimension-um X``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from edofproj.config import load_config
from edofproj.doe import build_doe, save_doe
from edofproj.fabrication import CriticalDimensionError, export_doe
from edofproj.fileio import write_text_atomic


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--doe", default=None, help="a run directory with doe.npz or a DOE .npz (default: an axicon)")
    parser.add_argument("--critical-dimension-um", type=float, default=1.0, help="narrowest printable feature (1 um)")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    cfg = load_config(None, ["doe.design_wavelength_nm=550"])  # the paper's design wavelength

    # 1. The design file. A trained run already holds one (RUN/doe.npz); here we tabulate the
    #    axicon of the default configuration on 1024 rings (--small: 256).
    if args.doe is not None:
        design = Path(args.doe)
        design = design / "doe.npz" if design.is_dir() else design
    else:
        design = out / "axicon_doe.npz"
        save_doe(build_doe(cfg, "axicon"), design, samples=512 if args.small else 2048)
    map_px = 256 if args.small else None  # the height-map preview; None: 2 px per narrowest zone

    # 2. Export at 16 levels (4 masks) and read the report.
    export_doe(
        design,
        out / "fab_16",
        levels=16,
        critical_dimension_um=args.critical_dimension_um,
        spectrum_cfg=cfg.spectrum,
        map_px=map_px,
    )
    with open(out / "fab_16" / "fab_report.json", encoding="utf-8") as handle:
        report = json.load(handle)
    print(f"{report['description']}")
    print(
        f"{report['levels']} levels, {report['masks_count']} masks, step {report['step_nm']:.2f} nm, "
        f"one wave h2pi = {report['h2pi_nm']:.1f} nm in {report['material']}; "
        f"{report['design_rings']} design rings -> {report['zones']} zones"
    )
    print("mask  GDS layer  etch (nm)  rings  narrowest feature (um)  below CD")
    for mask in report["masks"]:
        print(
            f"{mask['mask']:>4}  {mask['gds_layer']:>9}  {mask['etch_depth_nm']:>9.1f}  {mask['rings']:>5}  "
            f"{mask['narrowest_feature_um']:>22.3f}  {mask['features_below_cd']:>8}"
        )
    verdict = "passes" if report["passes_critical_dimension"] else "FAILS"
    narrowest = min(m["narrowest_feature_um"] for m in report["masks"] if m["narrowest_feature_um"])
    print(f"narrowest feature {narrowest:.3f} um: the design {verdict} the {args.critical_dimension_um:g} um CD")
    efficiency = report["efficiency"]
    print(
        f"first-order efficiency at {report['design_wavelength_nm']:.0f} nm: "
        f"{100 * efficiency['design_wavelength']:.2f} % (sinc^2(1/16) = {100 * np.sinc(1 / 16) ** 2:.2f} %); "
        "per primary: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in efficiency["per_channel_spd_weighted"].items())
    )

    # 3. Fewer masks: coarser levels are cheaper to make and have wider features, but throw more
    #    light out of the first order (into haze).
    trade_off = []
    print("levels  masks  narrowest feature (um)  efficiency at 550 nm")
    for levels in (16, 8, 4, 2):
        coarse = export_doe(
            design,
            out / f"fab_{levels}",
            levels=levels,
            critical_dimension_um=args.critical_dimension_um,
            spectrum_cfg=cfg.spectrum,
            map_px=map_px,
        )
        width = min(m["narrowest_feature_um"] for m in coarse["masks"] if m["narrowest_feature_um"])
        eta = coarse["efficiency"]["design_wavelength"]
        trade_off.append({"levels": levels, "masks": coarse["masks_count"], "narrowest_um": width, "efficiency": eta})
        print(f"{levels:>6}  {coarse['masks_count']:>5}  {width:>22.3f}  {100 * eta:>19.1f} %")

    # 4. A process that cannot print the narrowest feature: strict mode refuses and writes nothing.
    coarse_cd = 2.0 * narrowest
    try:
        export_doe(design, out / "fab_strict", critical_dimension_um=coarse_cd, strict=True, map_px=map_px)
        strict_message = None
    except CriticalDimensionError as exc:
        strict_message = str(exc)
    print(f"strict export at a {coarse_cd:.2f} um CD: {strict_message}")

    summary = {
        "design": str(design),
        "report": report,
        "narrowest_um": narrowest,
        "trade_off": trade_off,
        "strict_cd_um": coarse_cd,
        "strict_message": strict_message,
        "strict_wrote": (out / "fab_strict").exists(),
        "seconds": time.perf_counter() - start,
    }
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out}/fab_16, fab_8, fab_4, fab_2 and summary.json ({summary['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
