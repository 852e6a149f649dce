"""Evaluation of real captures (paper Table 2): captured projections scored against their targets.

Layout::

    targets/            one image per target (projector output light, the projector's size)
    captures/lens/      raw camera captures, one per target, named like it (any image extension)
    captures/lens+net/  ... one folder per method, as the user names them
    captures/doe+net/

Each raw capture ``c`` is rectified into projector output light per projector pixel,
``o = M^-1 (c(q(x)) - c_black(q(x)))`` (:meth:`ProCamsCalibration.to_output_space`), clipped
to ``[0, 1]`` and scored against its target with PSNR and SSIM (:mod:`edofproj.metrics`), and
LPIPS (AlexNet) and DISTS where their weights are present. Written (atomically, one folder):
``scores.csv`` (one row per method and image), ``comparison.png`` (targets and rectified
captures side by side), ``report.md`` and ``report.html`` (the table of means per method).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError
from ..imaging.image_io import IMAGE_EXTENSIONS, read_image_array, to_unit_float
from ..metrics import available_perceptual_metrics, perceptual_metric, psnr, ssim
from ..procams.calibration import ProCamsCalibration
from ..procams.capture_io import atomic_folder, read_rgb
from .figures import plot_captured_comparison
from .report import Figure, Heading, Paragraph, Report, Table

#: Perceptual metrics scored when their weights are present: ``{metric name: column}``.
PERCEPTUAL_COLUMNS = {"lpips-alex": "lpips", "dists": "dists"}
FIGURE_ROWS = 4


def _images(folder: Path) -> dict[str, Path]:
    """``{stem: path}`` of the image files in ``folder``."""
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()}


def _tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(image, dtype=np.float32).transpose(2, 0, 1)))[None]


@dataclass
class CaptureEvaluation:
    """Scores ``{method: {image: {metric: value}}}`` and the metrics scored, in column order."""

    metrics: list[str]
    scores: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    def means(self, method: str) -> dict[str, float]:
        rows = self.scores[method].values()
        return {m: float(np.mean([row[m] for row in rows])) for m in self.metrics}

    def summary_lines(self) -> list[str]:
        header = f"{'method':<16}" + "".join(f"{m:>10}" for m in self.metrics)
        lines = [header]
        for method in self.scores:
            means = self.means(method)
            lines.append(f"{method:<16}" + "".join(f"{means[m]:>10.4f}" for m in self.metrics))
        return lines

    def csv_text(self) -> str:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(["method", "image"] + self.metrics)
        for method, images in self.scores.items():
            for image, row in images.items():
                writer.writerow([method, image] + [f"{row[m]:.6g}" for m in self.metrics])
        return buffer.getvalue()


def read_methods(targets_dir: Path, captures_dir: Path) -> tuple[dict[str, Path], dict[str, dict[str, Path]]]:
    """The targets ``{stem: path}`` and, per method sub-folder, its captures of every target.

    Raises one line for a missing folder, a folder without images, or a method lacking captures.
    """
    for folder, what in ((targets_dir, "--targets"), (captures_dir, "--captures")):
        if not folder.is_dir():
            raise EdofprojError(f"{what} folder '{folder}' does not exist")
    targets = _images(targets_dir)
    if not targets:
        raise EdofprojError(f"--targets folder '{targets_dir}' holds no image ({', '.join(IMAGE_EXTENSIONS)})")
    methods = {}
    for sub in sorted(p for p in captures_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
        captures = _images(sub)
        missing = sorted(set(targets) - set(captures))
        if missing:
            raise EdofprojError(
                f"method '{sub.name}' lacks captures of {len(missing)} of {len(targets)} targets: {', '.join(missing[:5])}"
            )
        methods[sub.name] = {stem: captures[stem] for stem in targets}
    if not methods:
        raise EdofprojError(
            f"--captures folder '{captures_dir}' has no sub-folder (one per method, e.g. lens, doe+net)"
        )
    return targets, methods


def evaluate_captures(
    targets_dir: str | Path,
    captures_dir: str | Path,
    calib: str | Path | ProCamsCalibration,
    out_dir: str | Path,
    weights_dir: str | Path | None = None,
    overwrite: bool = False,
) -> CaptureEvaluation:
    """Score every method's rectified captures against the targets and write the report (module docstring)."""
    calibration = calib if isinstance(calib, ProCamsCalibration) else ProCamsCalibration.load(calib)
    targets, methods = read_methods(Path(targets_dir), Path(captures_dir))
    available = available_perceptual_metrics(weights_dir)
    perceptual = {
        column: perceptual_metric(name, weights_dir) for name, column in PERCEPTUAL_COLUMNS.items() if available[name]
    }
    result = CaptureEvaluation(metrics=["psnr", "ssim"] + list(perceptual))
    figure_rows: list[tuple[str, np.ndarray, list[tuple[str, np.ndarray, dict]]]] = []
    with atomic_folder(out_dir, overwrite=overwrite) as tmp:
        for stem, path in targets.items():
            target = to_unit_float(read_image_array(path))
            calibration.check_projector_hw(target.shape[:2], what=f"target '{path.name}'")
            target_t = _tensor(target)
            tiles = []
            for method, captures in methods.items():
                rectified = np.clip(calibration.to_output_space(read_rgb(captures[stem], what="capture")), 0.0, 1.0)
                shown = _tensor(rectified)
                with torch.no_grad():
                    row = {"psnr": float(psnr(shown, target_t)[0]), "ssim": float(ssim(shown, target_t)[0])}
                    row.update({column: float(metric(shown, target_t)[0]) for column, metric in perceptual.items()})
                result.scores.setdefault(method, {})[stem] = row
                tiles.append((method, rectified, row))
            if len(figure_rows) < FIGURE_ROWS:
                figure_rows.append((stem, target, tiles))
        plot_captured_comparison(figure_rows, tmp / "comparison.png")
        (tmp / "scores.csv").write_text(result.csv_text(), encoding="utf-8")
        report = Report(title="Captured projections against their targets")
        report.add(
            Paragraph(
                f"{len(targets)} targets, {len(methods)} methods. Each raw capture is rectified into projector output "
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
            Figure(tmp / "comparison.png", f"The first {len(figure_rows)} targets and each method's rectified capture.")
        )
        report.write(tmp / "report.md", tmp / "report.html")
    return result
