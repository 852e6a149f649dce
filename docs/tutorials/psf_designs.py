"""Tutorial 1: simulate and compare the PSFs of four optical designs across depth.

    python docs/tutorials/psf_designs.py --out tutorial_out/psf_designs [--small]

Simulates the RGB PSFs of the bare lens, an axicon, a cubic phase plate and a multifocal DOE on
screens from 300 to 800 mm, prints two numbers per design and depth -- the in-window energy and
the energy in the central 3x3 projector pixels (a sharpness number) -- and writes the PSF files,
a table (``psf_metrics.csv``), ``summary.json`` and two figures into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from edofproj.config import load_config
from edofproj.doe import build_doe
from edofproj.fabrication.tolerance import energy_concentration
from edofproj.fileio import atomic_path, write_text_atomic
from edofproj.optics.psf_bank import design_engine, simulator_from_config
from edofproj.reporting.psf_plots import plot_psf_comparison

DESIGNS = ("lens", "axicon", "cubic", "multifocal")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)  # small tensors: one thread is fastest and predictable
    start = time.perf_counter()

    # 1. The configuration: the default projector (7 mm aperture, in focus at 500 mm, throw ratio
    #    1.5, 800 px wide) and RGB primaries. --small samples 3 wavelengths and a coarser pupil.
    overrides = ["psf.window=33"]
    depths_mm = np.arange(300.0, 801.0, 50.0)
    if args.small:
        overrides = [
            "psf.window=15",
            "psf.pupil_samples=512",
            "spectrum.wavelength_min_nm=460",
            "spectrum.wavelength_max_nm=620",
            "spectrum.wavelength_step_nm=80",
        ]
        depths_mm = np.array([300.0, 500.0, 800.0])
    cfg = load_config(None, ["doe.design_wavelength_nm=550"] + overrides)  # the paper's design wavelength
    depths_m = depths_mm * 1e-3

    # 2. One simulator per propagation engine: the radial engine for the radially symmetric designs,
    #    the 2-D FFT engine for the cubic phase plate (design_engine picks it).
    simulators = {}
    panels = []
    rows = []
    for name in DESIGNS:
        doe = build_doe(cfg, name)
        engine = design_engine(doe, cfg.psf.engine)
        if engine not in simulators:
            simulators[engine] = simulator_from_config(cfg, engine=engine)
        bank = simulators[engine].bank(doe, depths_m)
        bank.save(out / f"psf_{name}.npz")
        panels.append((name, doe, bank))

        # 3. Two numbers per depth, each the mean over R, G, B: the share of the pupil energy inside
        #    the window (the rest becomes haze) and inside the central 3x3 pixels (sharpness).
        energy = bank.energy_in_window.mean(dim=1).numpy()
        sharpness = energy_concentration(bank.psf).mean(dim=1).numpy()
        for z, e, s in zip(depths_mm, energy, sharpness):
            rows.append({"design": name, "depth_mm": float(z), "energy_in_window": float(e), "energy_3x3": float(s)})

    # 4. The table, worst depth per design, and the figures.
    print(f"{'design':<14}" + "".join(f"{z:>8.0f}" for z in depths_mm) + "   (mm)")
    summary = {}
    for name in DESIGNS:
        mine = [r for r in rows if r["design"] == name]
        sharp = np.array([r["energy_3x3"] for r in mine])
        energy = np.array([r["energy_in_window"] for r in mine])
        print(f"{name + ' E':<14}" + "".join(f"{v:8.3f}" for v in energy))
        print(f"{name + ' 3x3':<14}" + "".join(f"{v:8.3f}" for v in sharp))
        summary[name] = {
            "energy_in_window": energy.tolist(),
            "energy_3x3": sharp.tolist(),
            "worst_energy_3x3": float(sharp.min()),
            "worst_depth_mm": float(depths_mm[int(np.argmin(sharp))]),
            "spread_energy_3x3": float(sharp.max() / sharp.min()),
        }
    print(
        "worst 3x3 energy over the range (depth): "
        + ", ".join(
            f"{n} {summary[n]['worst_energy_3x3']:.3f} ({summary[n]['worst_depth_mm']:.0f} mm)" for n in DESIGNS
        )
    )

    lines = ["design,depth_mm,energy_in_window,energy_3x3"]
    lines += [f"{r['design']},{r['depth_mm']:g},{r['energy_in_window']:.6f},{r['energy_3x3']:.6f}" for r in rows]
    write_text_atomic(out / "psf_metrics.csv", "\n".join(lines) + "\n")
    plot_psf_comparison(panels, out / "psf_designs.png")
    plot_sharpness(rows, out / "sharpness_vs_depth.png")
    summary["depths_mm"] = depths_mm.tolist()
    summary["seconds"] = time.perf_counter() - start
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(
        f"wrote {out}/psf_*.npz, psf_metrics.csv, psf_designs.png, sharpness_vs_depth.png ({summary['seconds']:.0f} s)"
    )


def plot_sharpness(rows: list[dict], path: Path) -> None:
    """Energy in the central 3x3 pixels against depth, one line per design."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.4), layout="constrained")
    for name in DESIGNS:
        mine = [r for r in rows if r["design"] == name]
        ax.plot([r["depth_mm"] for r in mine], [r["energy_3x3"] for r in mine], "o-", ms=3, label=name)
    ax.set_xlabel("screen depth (mm)")
    ax.set_ylabel("energy in central 3x3 px")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
