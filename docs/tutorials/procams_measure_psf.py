"""Tutorial 4: calibrate a projector-camera system and measure a PSF with the virtual ProCams.

    python docs/tutorials/procams_measure_psf.py --out tutorial_out/procams [--doe lens] [--depth-mm 350] [--small]

Builds the calibration and PSF-measurement patterns, captures them with a simulated projector and
camera (projector gamma, camera pose and lens distortion, colour mixing, ambient light, noise,
8-bit), calibrates the system (camera -> projector map, colour mixing, projector response),
measures the PSF from the Bernoulli-noise captures (paper Eq. 13) and compares it with the PSF
the simulation used. Writes ``calib.npz``, ``psf_measured.npz`` and ``psf_true.npz`` (the
``edofproj psf`` format), ``summary.json`` and a figure into ``--out``.
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
from edofproj.fileio import atomic_path, write_text_atomic
from edofproj.optics.geometry import ProjectorGeometry
from edofproj.optics.psf_bank import design_engine, simulator_from_config
from edofproj.procams import PatternSpec, VirtualProCams, build_pattern_set, calibrate, measure_psf
from edofproj.procams.calibration import calibration_files
from edofproj.procams.capture_io import write_rgb_png
from edofproj.procams.psf_estimation import bernoulli_files
from edofproj.reporting.psf_plots import psf_to_rgb


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--doe", default="lens", help="design whose PSF the virtual projector has (lens)")
    parser.add_argument("--depth-mm", type=float, default=350.0, help="screen distance, mm (350)")
    parser.add_argument("--small", action="store_true", help="tiny sizes: runs in seconds (for CI)")
    return parser.parse_args()


def l1_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """``sum |p_est - p_true| / sum p_true``."""
    return float(np.abs(estimate - truth).sum() / truth.sum())


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    start = time.perf_counter()
    if args.small:
        height, width, window, dots, levels = 96, 128, 15, (6, 8), 3
    else:
        height, width, window, dots, levels = 240, 320, 21, (12, 16), 5

    # 1. The ground truth: the RGB PSF of the design at the screen depth (the projector of the
    #    default configuration, 800 px wide: the patterns cover a width x height part of its image).
    cfg = load_config(None, [f"psf.window={window}"])
    depth_m = args.depth_mm * 1e-3
    doe = build_doe(cfg, args.doe)
    with torch.no_grad():
        true_psf = simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine)).bank(doe, [depth_m])
    psf = true_psf.psf[0].double().numpy()  # (3, K, K)

    # 2. The patterns: Bernoulli noise, a dot grid, full fields and colour samples.
    manifest, patterns = build_pattern_set(
        PatternSpec(width=width, height=height, bernoulli_count=5, dot_grid=dots, color_levels=levels)
    )
    print(
        f"{len(patterns)} patterns of {width}x{height} px: {len(manifest.with_role('bernoulli'))} Bernoulli, "
        f"{dots[0]}x{dots[1]} dots, {len(manifest.with_role('color_sample'))} colour samples"
    )

    # 3. A virtual projector-camera system; it plays projector and camera for every pattern.
    #    (With real hardware: project each pattern, capture it with a RAW camera, and read the
    #    captures back with edofproj.procams.capture_io.read_captures.)
    pitch_m = float(ProjectorGeometry.from_config(cfg.optics).pixel_pitch_m(depth_m))
    rig = VirtualProCams.example((height, width), psf, seed=1, depth_m=depth_m, pixel_pitch_m=pitch_m)
    rng = np.random.default_rng(1)
    captures = {f: rig.capture(patterns[f], rng) for f in calibration_files(manifest) + bernoulli_files(manifest)}
    print(
        f"camera {rig.camera_hw[1]}x{rig.camera_hw[0]} px, "
        f"{rig.camera_pixels_per_projector_pixel():.2f} camera px per projector px"
    )
    write_rgb_png(out / "capture_dots.png", captures[manifest.one("dots").file])
    write_rgb_png(out / "capture_bernoulli_00.png", captures[bernoulli_files(manifest)[0]])

    # 4. Calibrate: camera -> projector map (dots), colour-mixing matrix (primaries), response (samples).
    calibration = calibrate(manifest, captures)
    calibration.save(out / "calib.npz")
    true_x, true_y = rig.true_camera_map()
    camera_map = calibration.camera_map
    map_error_px = np.hypot(camera_map.map_x - true_x, camera_map.map_y - true_y) / (
        rig.camera_pixels_per_projector_pixel()
    )
    truth = rig.effective_mixing_matrix
    mixing_error = float(np.abs(calibration.color.mixing_matrix - truth).max() / np.abs(truth).max())
    map_rms = float(np.sqrt(np.mean(map_error_px**2)))
    print(f"camera map: rms error {map_rms:.3f} projector px; mixing matrix: max error {100 * mixing_error:.3f} %")

    # 5. Measure the PSF from the Bernoulli captures (Eq. 13) and compare it with the truth.
    estimate = measure_psf(manifest, patterns, captures, calibration, window)
    estimate.to_bank(depth_m, pitch_m, description="measured with the virtual ProCams").save(out / "psf_measured.npz")
    true_psf.save(out / "psf_true.npz")
    errors = [l1_error(estimate.psf[c], psf[c]) for c in range(3)]
    energy_true = psf.sum(axis=(-1, -2))
    energy_measured = estimate.energy_in_window
    print("PSF L1 error per channel (R, G, B): " + ", ".join(f"{100 * e:.1f} %" for e in errors))
    print(
        "in-window energy (R, G, B): measured "
        + ", ".join(f"{e:.4f}" for e in energy_measured)
        + "; true "
        + ", ".join(f"{e:.4f}" for e in energy_true)
    )

    plot_comparison(psf, estimate.psf, errors, out / "psf_true_vs_measured.png")
    summary = {
        "doe": args.doe,
        "depth_mm": args.depth_mm,
        "projector_hw": [height, width],
        "camera_hw": list(rig.camera_hw),
        "window": window,
        "l1_error": errors,
        "energy_true": energy_true.tolist(),
        "energy_measured": energy_measured.tolist(),
        "camera_map_rms_px": map_rms,
        "mixing_matrix_max_error": mixing_error,
        "seconds": time.perf_counter() - start,
    }
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(
        f"wrote {out}/calib.npz, psf_measured.npz, psf_true.npz, psf_true_vs_measured.png ({summary['seconds']:.0f} s)"
    )


def plot_comparison(true_psf: np.ndarray, measured: np.ndarray, errors: list[float], path: Path) -> None:
    """The true and the measured RGB PSF side by side, and their centre rows (green channel)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(9, 3), layout="constrained")
    axes[0].imshow(psf_to_rgb(true_psf), interpolation="nearest")
    axes[0].set_title("true PSF", fontsize=9)
    axes[1].imshow(psf_to_rgb(np.clip(measured, 0, None)), interpolation="nearest")
    axes[1].set_title(f"measured (L1 error G {100 * errors[1]:.1f} %)", fontsize=9)
    for ax in axes[:2]:
        ax.set_xticks([])
        ax.set_yticks([])
    K = true_psf.shape[-1]
    offsets = np.arange(K) - K // 2
    axes[2].plot(offsets, true_psf[1, K // 2], "k-", label="true")
    axes[2].plot(offsets, measured[1, K // 2], "o", ms=3, color="tab:green", label="measured")
    axes[2].set_xlabel("pixel offset (centre row, green)")
    axes[2].set_ylabel("fraction of pupil energy")
    axes[2].legend(fontsize=8)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
