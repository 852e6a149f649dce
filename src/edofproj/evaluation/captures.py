"""Evaluation of real captures (paper Table 2): captured projections scored against their targets.

Layout::

    targets/            one image per target (projector output light, the projector's size)
    captures/lens/      raw camera captures, one per target, named like it (any image extension)
    captures/lens+net/  ... one folder per method, as the user names them
    captures/doe+net/

Each raw capture ``c`` is rectified into projector output light per projector pixel,
``o = M^-1 (c(q(x)) - c_black(q(x)))`` (:meth:`ProCamsCalibration.to_output_space`), clipped
to ``[0, 1]`` and scored against its target with PSNR and SSIM (:mod:`edofproj.metrics`), and
LPIPS (AlexNet) and DISTS where their weights are present (:func:`score_captures`). The files,
``scores.csv`` and the report, are :func:`edofproj.reporting.captures.evaluate_captures`'s.
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
from ..procams.capture_io import read_rgb

#: Perceptual metrics scored when their weights are present: ``{metric name: column}``.
PERCEPTUAL_COLUMNS = {"lpips-alex": "lpips", "dists": "dists"}
#: How many targets keep their rectified captures as examples (the report's figure).
EXAMPLE_ROWS = 4


def _images(folder: Path) -> dict[str, Path]:
    """``{stem: path}`` of the image files in ``folder``."""
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()}


def _tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(image, dtype=np.float32).transpose(2, 0, 1)))[None]


@dataclass
class CaptureEvaluation:
    """Scores ``{method: {image: {metric: value}}}``, the metrics scored (in column order) and examples:
    ``(target name, target (H, W, 3), [(method, rectified capture (H, W, 3), scores), ...])`` of the
    first targets."""

    metrics: list[str]
    scores: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    examples: list[tuple[str, np.ndarray, list[tuple[str, np.ndarray, dict]]]] = field(default_factory=list)

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


def score_captures(
    targets: dict[str, Path],
    methods: dict[str, dict[str, Path]],
    calibration: ProCamsCalibration,
    weights_dir: str | Path | None = None,
    examples: int = EXAMPLE_ROWS,
) -> CaptureEvaluation:
    """Score every method's rectified captures against the targets (:func:`read_methods`; module
    docstring), keeping the first ``examples`` targets' rectified captures."""
    available = available_perceptual_metrics(weights_dir)
    perceptual = {
        column: perceptual_metric(name, weights_dir) for name, column in PERCEPTUAL_COLUMNS.items() if available[name]
    }
    result = CaptureEvaluation(metrics=["psnr", "ssim"] + list(perceptual))
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
        if len(result.examples) < examples:
            result.examples.append((stem, target, tiles))
    return result
