"""Design a DOE for a real multi-element projector lens (a lens prescription read through Optiland).

Run from the repository root:

    python docs/tutorials/lens_doe.py --out tutorial_out/lens_doe [--lens MY_LENS.zmx] [--small]

Without ``--lens`` it writes Optiland's example Cooke triplet (F/5, f = 50 mm, 20 degree field) as a
Zemax file and uses that. Needs the lens extra: ``pip install -e '.[lens]'``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from edofproj.config import load_config
from edofproj.doe import build_doe
from edofproj.fabrication.tolerance import energy_concentration
from edofproj.fileio import write_text_atomic
from edofproj.optics.lens_prescription import entrance_pupil_diameter_mm, load_prescription
from edofproj.optics.psf_bank import simulator_from_config


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--lens", help="a .zmx or Optiland .json prescription (default: the Cooke triplet)")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def write_example_lens(path: Path) -> None:
    """Optiland's example Cooke triplet, written as a Zemax file with Optiland's own writer."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from optiland.fileio import save_zemax_file
        from optiland.samples.objectives import CookeTriplet

        save_zemax_file(CookeTriplet(), str(path))


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    start = time.perf_counter()

    # 1. The lens: a prescription file, read (and later ray traced) by Optiland.
    lens_path = Path(args.lens) if args.lens else out / "cooke_triplet.zmx"
    if not args.lens:
        write_example_lens(lens_path)
    lens = load_prescription(lens_path)
    epd_mm = entrance_pupil_diameter_mm(lens)

    # 2. The projector around it: the aperture is the lens's entrance pupil; the throw ratio puts the
    #    image's corner at the lens's full field (20 degrees for the triplet: 1920 x 1080 px,
    #    T = half-diagonal / tan 20 deg / width = 1.58); in focus at 1 m, scored from 0.8 to 1.3 m.
    throw = round(0.5 * math.hypot(1920, 1080) / 1920 / math.tan(math.radians(20.0)), 2)
    overrides = [
        f"optics.lens_prescription={lens_path}",
        f"optics.aperture_mm={epd_mm:.6g}",
        "optics.focus_mm=1000",
        "optics.width_px=1920",
        "optics.height_px=1080",
        f"optics.throw_ratio={throw}",
        "psf.engine=2d",
        "psf.window=21",
        "psf.pupil_samples=768",
        "spectrum.wavelength_min_nm=460",
        "spectrum.wavelength_max_nm=620",
        "spectrum.wavelength_step_nm=40",
    ]
    depths_mm = np.array([800.0, 900.0, 1000.0, 1150.0, 1300.0])
    fields = [(0.0, 0.0), (0.0, 0.7)]
    strengths = [0.0, 2.0, 4.0, 6.0, 8.0]
    if args.small:
        overrides += ["psf.pupil_samples=512", "spectrum.wavelength_step_nm=80"]
        depths_mm = np.array([800.0, 1000.0, 1300.0])
        strengths = [0.0, 3.0, 6.0]
    depths_m = depths_mm * 1e-3

    # 3. The design: a cubic phase plate phi = 2 pi alpha (x^3 + y^3) / R^3 at the stop, its
    #    strength alpha chosen for the largest worst-case sharpness (energy in the central 3x3
    #    pixels, mean of R, G, B) over the depths and two field points of the traced lens.
    table = {}
    for field in fields:
        cfg = load_config(None, overrides + [f"optics.lens_field=[{field[0]}, {field[1]}]"])
        sim = simulator_from_config(cfg)  # traces the lens at this field point, every wavelength
        if field == fields[0]:
            print(
                f"lens {lens_path.name}: entrance pupil {epd_mm:.3g} mm, RMS wavefront at 540 nm: "
                + ", ".join(f"{sim.engine.aberration.rms_um(540.0) * 1000:.0f} nm on axis" for _ in [0])
            )
        else:
            print(f"  at field {field}: RMS wavefront {sim.engine.aberration.rms_um(540.0) * 1000:.0f} nm")
        for alpha in strengths:
            cfg.doe.cubic_waves = alpha
            doe = build_doe(cfg, "cubic")
            with torch.no_grad():
                sharp = energy_concentration(sim(doe, depths_m)).mean(dim=1).numpy()
            table[(field, alpha)] = sharp

    print(f"{'alpha (waves)':<22}" + "".join(f"{z:>8.0f}" for z in depths_mm) + "   (mm): energy in 3x3")
    worst = {}
    for alpha in strengths:
        for field in fields:
            row = table[(field, alpha)]
            print(f"{alpha:>5g} at field {field[1]:<4g}     " + "".join(f"{v:8.3f}" for v in row))
        worst[alpha] = float(min(table[(f, alpha)].min() for f in fields))
    best = max(strengths, key=lambda a: worst[a])
    print(
        "worst case over depths and fields: "
        + ", ".join(f"alpha {a:g}: {worst[a]:.3f}" for a in strengths)
        + f"; chosen alpha = {best:g} waves"
    )

    lines = ["field_x,field_y,alpha_waves,depth_mm,energy_3x3"]
    for (field, alpha), row in table.items():
        lines += [f"{field[0]:g},{field[1]:g},{alpha:g},{z:g},{v:.6f}" for z, v in zip(depths_mm, row)]
    write_text_atomic(out / "lens_doe_metrics.csv", "\n".join(lines) + "\n")
    summary = {
        "lens": str(lens_path),
        "entrance_pupil_mm": epd_mm,
        "throw_ratio": throw,
        "depths_mm": depths_mm.tolist(),
        "strengths_waves": strengths,
        "worst_energy_3x3": {f"{a:g}": worst[a] for a in strengths},
        "chosen_alpha_waves": best,
        "seconds": time.perf_counter() - start,
    }
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out}/lens_doe_metrics.csv, summary.json ({summary['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
