"""What an evaluation on 3-D scenes shows and says (:mod:`edofproj.evaluation.scenes`).

:func:`write_scene_report` draws ``figures/eval_scenes.png`` (rows = scenes, columns = the target
on the object and each method, the first image) and ``figures/eval_scene_ssim.png`` (the local
SSIM maps of the same tiles), and writes ``scene_summary.md``: the mean SSIM and PSNR over the
objects' pixels per scene and method (:func:`scene_summary_table`).
"""

from __future__ import annotations

from ..evaluation.scenes import SCENE_METRICS_NAME, SceneEvaluation
from ..runs import FIGURES_DIR
from .document import Paragraph, Report, Table
from .figures import plot_scene_grid, plot_scene_ssim_maps

SCENE_SUMMARY_NAME = "scene_summary.md"


def scene_summary_table(evaluation: SceneEvaluation, metric: str = "ssim", digits: int = 3) -> Table:
    """Rows ``[scene (depths), mean metric per method...]`` over the images."""
    rows = []
    for scene in evaluation.scenes:
        lo, hi = evaluation.depth_ranges_mm[scene]
        cells = [f"{scene} ({lo:.0f}-{hi:.0f} mm)"]
        for method in evaluation.methods:
            cells.append(f"{evaluation.table.mean(metric, method=method, scene=scene):.{digits}f}")
        rows.append(cells)
    return Table(["scene (depths seen)"] + evaluation.methods, rows)


def write_scene_report(evaluation: SceneEvaluation) -> None:
    """The scene figures and ``scene_summary.md`` in ``evaluation.out_dir`` (paths in ``evaluation.files``:
    ``figure``, ``ssim_figure``, ``summary``)."""
    figures = evaluation.out_dir / FIGURES_DIR
    figures.mkdir(parents=True, exist_ok=True)
    evaluation.files["figure"] = figures / "eval_scenes.png"
    plot_scene_grid(
        evaluation.targets, evaluation.examples, evaluation.scenes, evaluation.methods, evaluation.files["figure"]
    )
    evaluation.files["ssim_figure"] = figures / "eval_scene_ssim.png"
    plot_scene_ssim_maps(evaluation.examples, evaluation.scenes, evaluation.methods, evaluation.files["ssim_figure"])
    images = len({row["image"] for row in evaluation.table.rows})
    report = Report(f"Scenes: {evaluation.run_dir}")
    report.extend(
        [
            Paragraph(
                f"SSIM over the objects' pixels, mean of {images} image(s) at the panel size; "
                f"`{SCENE_METRICS_NAME}` has every score (PSNR too)."
            ),
            scene_summary_table(evaluation, "ssim"),
            Paragraph("PSNR (dB) over the objects' pixels:"),
            scene_summary_table(evaluation, "psnr", digits=2),
        ]
    )
    evaluation.files["summary"] = evaluation.out_dir / SCENE_SUMMARY_NAME
    report.write(markdown_path=evaluation.files["summary"])
