"""Outputs of a tolerance run: ``tolerance.csv``, ``tolerance.md``, ``tolerance.json`` and ``tolerance.png``.

Each file is written atomically (:mod:`edofproj.fileio`). The CSV has one row per depth:
``depth_mm,nominal,median,p05,p95,min,max`` of the energy concentration (and the same for
SSIM when it was evaluated).
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..errors import EdofprojError  # noqa: E402
from ..fileio import atomic_path, write_text_atomic  # noqa: E402
from .tolerance import CONCENTRATION_BOX_PX, ToleranceResult  # noqa: E402

CSV_NAME = "tolerance.csv"
MD_NAME = "tolerance.md"
JSON_NAME = "tolerance.json"
PNG_NAME = "tolerance.png"

MODEL_TEXT = {
    "radial": "radial engine; overlay errors as the radially symmetric proxy (every edge of mask j moved "
    "outward by the x-component of its shift, revolved about the axis: the full shift at every "
    "azimuth, so it overstates overlay errors), simulated exactly on rings split at every edge; "
    "no decentre",
    "2d": "2-D engine; true lateral shifts of each mask and of the whole DOE, point-sampled on the engine's grid",
}


def _stats(values: np.ndarray, nominal: np.ndarray) -> dict:
    p05, p50, p95 = np.percentile(values, (5.0, 50.0, 95.0), axis=0)
    return {
        "nominal": nominal,
        "median": p50,
        "p05": p05,
        "p95": p95,
        "min": values.min(axis=0),
        "max": values.max(axis=0),
    }


def table_columns(result: ToleranceResult) -> dict:
    """The per-depth table as named columns, each an array of shape (Z,): ``depth_mm``, then the energy
    concentration's ``nominal``, ``median``, ``p05``, ``p95``, ``min`` and ``max`` over the T trials, then
    the same with an ``ssim_`` prefix when the result has SSIM trials. Raises
    :class:`~edofproj.errors.EdofprojError` if it has SSIM trials but no nominal SSIM."""
    columns = {"depth_mm": result.depths_m * 1e3}
    columns.update(_stats(result.trials, result.nominal))
    if result.ssim_trials is not None:
        if result.ssim_nominal is None:
            raise EdofprojError("the tolerance result has SSIM trials but no nominal SSIM")
        columns.update({f"ssim_{k}": v for k, v in _stats(result.ssim_trials, result.ssim_nominal).items()})
    return columns


def csv_text(result: ToleranceResult) -> str:
    """``tolerance.csv``: a header of the :func:`table_columns` names, then one row per depth, values with 6
    significant digits."""
    columns = table_columns(result)
    rows = [",".join(columns)]
    for i in range(len(result.depths_m)):
        rows.append(",".join(f"{columns[name][i]:.6g}" for name in columns))
    return "\n".join(rows) + "\n"


def markdown_text(result: ToleranceResult, source: str) -> str:
    """``tolerance.md``: the design ``source``, the error model's settings, the engine's model and the figure
    of merit, a table per depth (nominal, median, 5 %, 95 % and worst energy concentration), the median and
    5th-percentile relative change ``(trial - nominal) / nominal`` over all depths and trials, and the
    compensated-SSIM table (or a line saying it was not computed)."""
    s = result.settings
    columns = table_columns(result)
    lines = [
        "# Fabrication tolerance",
        "",
        f"Design: `{source}`",
        "",
        f"* {s.trials} Monte Carlo trials (seed {s.seed}): etch depth error {s.etch_error_pct:g} % (1 sigma, per mask), "
        f"overlay {s.misalignment_um:g} um (1 sigma per axis, masks 1.. against mask 0), "
        f"decentre {s.decentre_um:g} um (1 sigma per axis)",
        f"* Model: {MODEL_TEXT[s.engine]}",
        f"* Figure of merit: energy concentration, the fraction of the pupil energy within the central "
        f"{CONCENTRATION_BOX_PX}x{CONCENTRATION_BOX_PX} projector pixels (mean over R, G, B)",
        "",
        "| depth (mm) | nominal | median | 5 % | 95 % | worst |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for i in range(len(result.depths_m)):
        lines.append(
            f"| {columns['depth_mm'][i]:.0f} | {columns['nominal'][i]:.4f} | {columns['median'][i]:.4f} | "
            f"{columns['p05'][i]:.4f} | {columns['p95'][i]:.4f} | {columns['min'][i]:.4f} |"
        )
    relative = (result.trials - result.nominal) / np.maximum(result.nominal, 1e-12)
    lines += [
        "",
        f"Median change across depths and trials: {100 * np.median(relative):+.2f} %; "
        f"5th percentile: {100 * np.percentile(relative, 5):+.2f} %.",
    ]
    if result.ssim_trials is None:
        lines += [
            "",
            "Compensated SSIM: not computed (it needs a trained compensation network; "
            "`run_tolerance(..., evaluate_ssim=...)`).",
        ]
    else:
        lines += [
            "",
            "| depth (mm) | SSIM nominal | SSIM median | SSIM 5 % | SSIM 95 % |",
            "| --- | --- | --- | --- | --- |",
        ]
        for i in range(len(result.depths_m)):
            lines.append(
                f"| {columns['depth_mm'][i]:.0f} | {columns['ssim_nominal'][i]:.4f} | {columns['ssim_median'][i]:.4f} | "
                f"{columns['ssim_p05'][i]:.4f} | {columns['ssim_p95'][i]:.4f} |"
            )
    return "\n".join(lines) + "\n"


def json_data(result: ToleranceResult, source: str) -> dict:
    """``tolerance.json`` as a JSON-ready mapping: the source, the settings, the model text, the depths (mm),
    the nominal concentration (Z,) and per channel, every trial's concentration (T, Z) with its
    :meth:`FabricationErrors.as_dict` draw, and the SSIM arrays (None when not evaluated)."""
    return {
        "source": source,
        "settings": vars(result.settings),
        "model": MODEL_TEXT[result.settings.engine],
        "depths_mm": (result.depths_m * 1e3).tolist(),
        "nominal": result.nominal.tolist(),
        "nominal_per_channel": result.nominal_per_channel.tolist(),
        "trials": result.trials.tolist(),
        "errors": [e.as_dict() for e in result.errors],
        "ssim_nominal": None if result.ssim_nominal is None else result.ssim_nominal.tolist(),
        "ssim_trials": None if result.ssim_trials is None else result.ssim_trials.tolist(),
    }


def plot(result: ToleranceResult, path: Path) -> None:
    """Median and 5-95 % band of the energy concentration vs depth, nominal overlaid (and SSIM if any)."""
    panels = [("trials", "nominal", f"energy in central {CONCENTRATION_BOX_PX}x{CONCENTRATION_BOX_PX} px")]
    if result.ssim_trials is not None:
        panels.append(("ssim_trials", "ssim_nominal", "compensated SSIM"))
    fig, axes = plt.subplots(1, len(panels), figsize=(6.4 * len(panels), 4.0), dpi=120, squeeze=False)
    z = result.depths_m * 1e3
    for ax, (trials_attr, nominal_attr, label) in zip(axes[0], panels):
        values = getattr(result, trials_attr)
        p05, p50, p95 = np.percentile(values, (5.0, 50.0, 95.0), axis=0)
        ax.fill_between(z, p05, p95, color="tab:blue", alpha=0.25, lw=0, label="5-95 % of trials")
        ax.plot(z, p50, color="tab:blue", label="median")
        ax.plot(z, getattr(result, nominal_attr), "k--", marker="o", ms=3, label="nominal design")
        ax.set_xlabel("screen depth (mm)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    s = result.settings
    fig.suptitle(
        f"{s.trials} trials: etch {s.etch_error_pct:g} %, overlay {s.misalignment_um:g} um, "
        f"decentre {s.decentre_um:g} um ({s.engine})",
        fontsize=9,
    )
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)


def write_outputs(result: ToleranceResult, out_dir: str | Path, source: str) -> list[Path]:
    """Write the four outputs into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / CSV_NAME, out / MD_NAME, out / JSON_NAME, out / PNG_NAME]
    write_text_atomic(paths[0], csv_text(result))
    write_text_atomic(paths[1], markdown_text(result, source))
    write_text_atomic(paths[2], json.dumps(json_data(result, source), indent=2) + "\n")
    plot(result, paths[3])
    return paths
