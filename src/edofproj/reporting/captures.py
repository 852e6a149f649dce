"""``procams evaluate``: real captures scored (:mod:`edofproj.evaluation.captures`) and their report.

Written atomically, into one folder: ``scores.csv`` (one row per method and image),
``comparison.png`` (the first targets and each method's rectified capture side by side),
``report.md`` and ``report.html`` (the table of means per method and the figure).
"""

from __future__ import annotations

from pathlib import Path

from ..evaluation.captures import CaptureEvaluation, read_methods, score_captures
from ..procams.calibration import ProCamsCalibration
from ..procams.capture_io import atomic_folder
from .document import Figure, Heading, Paragraph, Report, Table
from .figures import plot_captured_comparison


def evaluate_captures(
    targets_dir: str | Path,
    captures_dir: str | Path,
    calib: str | Path | ProCamsCalibration,
    out_dir: str | Path,
    weights_dir: str | Path | None = None,
    overwrite: bool = False,
) -> CaptureEvaluation:
    """Score every method's rectified captures against the targets and write the scores and the report
    into ``out_dir`` (module docstring)."""
    calibration = calib if isinstance(calib, ProCamsCalibration) else ProCamsCalibration.load(calib)
    targets, methods = read_methods(Path(targets_dir), Path(captures_dir))
    with atomic_folder(out_dir, overwrite=overwrite, what="edofproj procams evaluate") as tmp:
        result = score_captures(targets, methods, calibration, weights_dir)
        (tmp / "scores.csv").write_text(result.csv_text(), encoding="utf-8")
        write_capture_report(result, tmp)
    return result


def write_capture_report(result: CaptureEvaluation, folder: Path) -> None:
    """``comparison.png``, ``report.md`` and ``report.html`` of ``result`` in ``folder``."""
    plot_captured_comparison(result.examples, folder / "comparison.png")
    targets = len(next(iter(result.scores.values())))
    perceptual = [m for m in result.metrics if m not in ("psnr", "ssim")]
    report = Report(title="Captured projections against their targets")
    report.add(
        Paragraph(
            f"{targets} targets, {len(result.scores)} methods. Each raw capture is rectified into projector output "
            "light per projector pixel with the calibration (geometric warp, black level, inverse colour mixing), "
            "clipped to [0, 1] and scored against its target."
            + ("" if perceptual else " LPIPS and DISTS are left out: their weights are not present.")
        )
    )
    report.add(Heading("Mean scores per method"))
    report.add(
        Table(
            header=["method"] + [m.upper() for m in result.metrics],
            rows=[[method] + [f"{v:.4f}" for v in result.means(method).values()] for method in result.scores],
            caption="PSNR in dB and SSIM: higher is better; LPIPS and DISTS: lower is better.",
        )
    )
    report.add(Heading("Side by side"))
    report.add(
        Figure(
            folder / "comparison.png", f"The first {len(result.examples)} targets and each method's rectified capture."
        )
    )
    report.write(folder / "report.md", folder / "report.html")
