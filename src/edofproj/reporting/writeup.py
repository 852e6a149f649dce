"""What an evaluation shows and says: its figures, ``summary.md`` and the report (``report.md`` +
``report.html``).

:func:`write_documents` is the one way an evaluation's report is written (``evaluate``, the demo):
it draws the figures (:func:`write_figures`) and writes the documents, assembled from an
:class:`~edofproj.evaluation.pipeline.Evaluation` as :mod:`.document` blocks; callers (the demo)
add their own sections before and after (the paper's claims, timing, wall time).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from ..doe import build_doe
from ..evaluation.results import METRIC_LABELS, format_span_mm, headline_metrics
from ..evaluation.sweep import tilted_range_mm
from ..methods.catalogue import METHOD_NAMES
from ..methods.designs import OpticalDesign
from ..methods.guard import GuardedNetworkCompensation
from ..progress import StageProgress
from ..runs import FIGURES_DIR
from ..runs.figures import plot_doe_profile
from ..runs.log import read_log
from .claims import Claim
from .designs import best_compensations, designs_caption
from .document import Bullets, Figure, Heading, Paragraph, Report, Table
from .figures import plot_comparison, plot_designs_vs_depth, plot_metric_vs_depth, plot_tilted, plot_training_curves
from .image_checks import behind_linear_filter_blocks, channel_imbalance_blocks
from .psf_plots import plot_psf_comparison
from .tables import depth_table, image_spread_table, range_table, tilted_table

SUMMARY_NAME = "summary.md"
REPORT_MD_NAME = "report.md"
REPORT_HTML_NAME = "report.html"

#: How the overview names each image set of an evaluation.
IMAGE_SET_LABELS = {
    "test": "held-out test",
    "validation": "validation (never training or test images)",
    "folder": "given",
}

REIMPLEMENTATION_NOTE = (
    "lens+onlineprodeb is our PyTorch re-implementation of OnlineProDeb (Kageyama, Iwai, Sato, TVCG 2022), "
    "trained on the same simulated lens-only data as lens+net; it is not the authors' code or weights "
    "(those are TensorFlow, grayscale 256x256 and inference-only)."
)


def overview(ev) -> list:
    run = ev.run
    images = ", ".join(name for name, _ in ev.images)
    size = ev.images[0][1].shape[-2:]
    lo, hi = ev.range_mm
    return [
        Paragraph(
            f"Run **{run.run_dir}** (step {run.step}): {ev.designs['run'].description if 'run' in ev.designs else run.doe.describe()}. "
            f"Projector: aperture {ev.cfg.optics.aperture_mm:g} mm, in focus at v = {ev.cfg.optics.focus_mm:g} mm, "
            f"throw ratio {ev.cfg.optics.throw_ratio:g}, {ev.cfg.optics.width_px} px wide; training depth range "
            f"{format_span_mm(ev.cfg.psf.depth_min_mm, ev.cfg.psf.depth_max_mm)} mm (psf.depth_min_mm-psf.depth_max_mm); "
            f"scored depth range {format_span_mm(lo, hi)} mm (the means and worst depths of the tables)."
        ),
        Paragraph(
            f"Scored on {len(ev.images)} {IMAGE_SET_LABELS.get(ev.image_set, 'held-out')} image(s) ({images}) "
            f"of {size[0]}x{size[1]} px, at "
            f"{len(ev.depths_mm)} flat-screen depths ({', '.join(f'{z:.0f}' for z in ev.depths_mm)} mm) and on a "
            f"tilted screen. Every projector input is clamped to [0, 1] and projected through the same image "
            f"formation (FFT convolution with the simulated RGB PSF plus the haze of the light outside the PSF "
            f"window). Networks receive the target and the simulated capture I* = project(I, p_z)."
        ),
    ]


def methods_section(ev) -> list:
    items = [f"**{m.name}**: {m.spec.summary}" + (f" ({m.detail})" if m.detail else "") for m in ev.methods]
    blocks = [Heading("Methods"), Bullets(items)]
    notes = list(ev.notes)
    evaluated = {m.name for m in ev.methods}
    if "lens+onlineprodeb" in evaluated:
        notes.append(REIMPLEMENTATION_NOTE)
    # a method a note already names (not trained in time, no run, ...) is not listed a second time
    noted = {note.split(" ", 1)[0] for note in notes}
    not_evaluated = [name for name in METHOD_NAMES if name not in evaluated and name not in noted]
    if not_evaluated:
        notes.append(f"Not evaluated: {', '.join(not_evaluated)}.")
    if ev.perceptual_missing:
        notes.append(
            f"Perceptual metrics unavailable on this machine (no pretrained weights): "
            f"{', '.join(m.upper() for m in ev.perceptual_missing)}; their columns are omitted, not zero."
        )
    notes.append(
        "Blind methods know nothing of the screen's depth or PSF at run time: no compensation, the networks "
        "(they see the target and the uncompensated capture) and doe+ensemble (one fixed filter for the whole "
        "depth range). Non-blind methods, Wiener and CLS, are given the exact PSF of each depth (on the tilted "
        "screen, the PSF of its middle column): an upper reference for a projector that measures depth."
    )
    if ev.frame_ms:
        notes.append(
            f"{frame_ms_caption(ev)}: the non-blind Wiener filter is computed for each frame (its PSF follows the "
            f"depth), CLS runs {ev.cfg.evaluation.cls_iterations} iterations, doe+ensemble and the networks are "
            f"fixed. A separate timing table (the demo's, `edofproj bench`) times the kernels alone at fixed sizes "
            f"(a network's forward pass without its guard): its figures differ from these."
        )
    blocks += [Heading("Notes", 3), Bullets(notes)]
    return blocks


def frame_ms_caption(ev) -> str:
    """What the summary's ms/frame measures, in one sentence: the frame size, the threads, and which
    networks ran with their display guard (its predicted displays are timed with them)."""
    height, width = ev.images[0][1].shape[-2:]
    guarded = [m.name for m in ev.methods if isinstance(m.compensate, GuardedNetworkCompensation)]
    return (
        f"ms/frame: median milliseconds of each method's whole compensation of one {height}x{width} frame as "
        f"evaluated, right after scoring ({ev.timing_threads} CPU thread(s) unless run on a GPU"
        + (f"; {', '.join(guarded)} with the display guard" if guarded else "")
        + ")"
    )


def results_tables(ev) -> list:
    blocks = [
        range_table(
            ev.table, ev.range_mm, frame_ms=ev.frame_ms, frame_ms_note=frame_ms_caption(ev) if ev.frame_ms else ""
        ),
        image_spread_table(ev.table, ev.range_mm),
    ]
    for metric in headline_metrics(ev.table.metrics):
        blocks.append(depth_table(ev.table, metric, ev.range_mm))
    return blocks


def image_checks_section(ev) -> list:
    """The network against its own DOE's linear filter per image (flags), and lost colour channels."""
    blocks = behind_linear_filter_blocks(ev.table, ev.range_mm) + channel_imbalance_blocks(ev.table, ev.range_mm)
    return [Heading("Per image: network vs linear filter, colour channels")] + blocks if blocks else []


def claims_section(claims: Sequence[Claim]) -> list:
    """The paper's claims as measured here: a verdict paragraph and a table."""
    rows = [[f"({c.key})", c.statement, c.verdict, c.measured] for c in claims]
    failed = [c for c in claims if c.holds is False]
    unmeasured = [c for c in claims if c.holds is None]
    if not all(c.judged for c in claims):
        verdict = "A smoke run: its images and training are too small to judge any claim."
    elif failed:
        verdict = "**Not every claim holds here**: " + "; ".join(f"({c.key}) does not hold" for c in failed) + "."
    elif unmeasured:
        verdict = "Some claims could not be measured: " + ", ".join(f"({c.key})" for c in unmeasured) + "."
    else:
        verdict = "Every claim holds on these images."
    return [
        Heading("Claims of the paper, on the evaluated images"),
        Paragraph(verdict),
        Table(["claim", "statement", "result", "measured"], rows),
    ]


def summary_report(ev) -> Report:
    """``summary.md``: the tables and the notes."""
    report = Report("Evaluation summary")
    report.extend(overview(ev))
    report.add(Heading("Flat screen"))
    report.extend(results_tables(ev))
    report.extend(image_checks_section(ev))
    report.add(Heading("Tilted screen"))
    report.add(tilted_table(ev.tilted))
    report.extend(methods_section(ev))
    return report


def _add_figure(report: Report, figures: dict, key: str, caption: str) -> None:
    """Add the figure ``figures[key]`` with its caption, if it was drawn."""
    if key in figures:
        report.add(Figure(figures[key], caption))


def full_report(ev, title: str = "edofproj evaluation", preface: Sequence = (), extra: Sequence = ()) -> Report:
    """The report: ``preface`` blocks, results, figures, methods and notes, then ``extra`` blocks."""
    report = Report(title)
    report.extend(overview(ev))
    report.extend(list(preface))
    report.add(Heading("Summary"))
    report.add(
        range_table(
            ev.table, ev.range_mm, frame_ms=ev.frame_ms, frame_ms_note=frame_ms_caption(ev) if ev.frame_ms else ""
        )
    )
    report.add(image_spread_table(ev.table, ev.range_mm))
    report.extend(image_checks_section(ev))
    figures = ev.figures
    report.add(Heading("Quality against depth"))
    for metric in headline_metrics(ev.table.metrics):
        _add_figure(
            report,
            figures,
            f"{metric}_vs_depth",
            f"{METRIC_LABELS.get(metric, metric)} against screen depth, mean over the "
            f"test images (scored depth range shaded).",
        )
    report.extend(results_tables(ev)[2:])
    if "designs_vs_depth" in figures:
        report.add(Heading("Each optical design at its best"))
        report.add(
            Figure(figures["designs_vs_depth"], designs_caption(best_compensations(ev.table, ev.range_mm), ev.range_mm))
        )
    report.add(Heading("Side-by-side comparison (paper Fig. 6)"))
    _add_figure(
        report,
        figures,
        "comparison",
        "Simulated projections of the first test image on flat screens at "
        + ", ".join(f"{z:.0f}" for z in sorted({z for z, _ in ev.comparison}))
        + " mm (depths of the tables, nearest to the paper's Fig. 6); "
        "PSNR (P), SSIM (S) of each tile, best of each row in red.",
    )
    report.add(Heading("Tilted screen (paper Sec. 5.3)"))
    report.add(tilted_table(ev.tilted))
    _add_figure(
        report,
        figures,
        "tilted",
        f"A plane screen tilted by {ev.cfg.evaluation.tilt_deg:g} deg, depth "
        f"from {tilted_range_mm(ev.cfg)[0]:.0f} to {tilted_range_mm(ev.cfg)[1]:.0f} mm (left to right), "
        f"rendered by {ev.cfg.imaging.depth_layers} depth layers.",
    )
    report.add(Heading("Optics"))
    _add_figure(
        report,
        figures,
        "psf",
        psf_caption(ev),
    )
    _add_figure(report, figures, "doe_profile", "Height profile of the learned DOE as fabricated (wrapped, quantized).")
    if "training" in figures:
        report.add(Heading("Training"))
        report.add(Figure(figures["training"], "Training loss of each run."))
    report.extend(list(extra))
    report.extend(methods_section(ev))
    return report


def psf_caption(ev) -> str:
    """The PSF figure's caption, naming the depths it shows (:func:`psf_figure_depths_m`)."""
    depths_mm = psf_figure_depths_m(ev.cfg) * 1e3
    near, far = ev.range_mm
    return (
        f"RGB PSFs at {', '.join(f'{z:.0f}' for z in depths_mm)} mm: the depth range the PSFs are simulated and "
        f"trained over (psf.depth_min_mm-psf.depth_max_mm; the scores cover {near:.0f}-{far:.0f} mm), bare lens vs "
        "the learned DOE (and baseline optics); E = energy inside the PSF window."
    )


def psf_figure_depths_m(cfg, count: int = 6) -> np.ndarray:
    """The depths of the PSF figure: ``count`` from ``psf.depth_min_mm`` to ``psf.depth_max_mm``."""
    return np.linspace(cfg.psf.depth_min_m, cfg.psf.depth_max_m, count)


def write_figures(ev) -> None:
    """The evaluation's figures in ``<out>/figures/eval_*.png`` (paths in ``ev.figures``)."""
    figures = ev.out_dir / FIGURES_DIR
    figures.mkdir(parents=True, exist_ok=True)
    for metric in headline_metrics(ev.table.metrics):
        path = figures / f"eval_{metric}_vs_depth.png"
        plot_metric_vs_depth(ev.table, metric, path, ev.range_mm)
        ev.figures[f"{metric}_vs_depth"] = path
    if "ssim" in ev.table.metrics:
        best = best_compensations(ev.table, ev.range_mm)
        if best:
            ev.figures["designs_vs_depth"] = figures / "eval_designs_vs_depth.png"
            plot_designs_vs_depth(ev.table, best, ev.figures["designs_vs_depth"], ev.range_mm)

    methods = [m.name for m in ev.methods]
    name, image = ev.images[0]
    target = image.permute(1, 2, 0).numpy()
    ev.figures["comparison"] = figures / "eval_comparison.png"
    plot_comparison(
        target,
        ev.comparison,
        sorted({z for z, _ in ev.comparison}),  # the rows computed: scored depths (nearest_scored_depths_mm)
        methods,
        ev.figures["comparison"],
        image_name=name,
    )
    if ev.tilted.rows:
        row = ev.tilted.rows[0]
        ev.figures["tilted"] = figures / "eval_tilted.png"
        plot_tilted(
            target,
            ev.tilted_examples,
            methods,
            ev.figures["tilted"],
            row["near_mm"],
            row["far_mm"],
            ev.cfg.evaluation.tilt_deg,
        )

    depths_m = psf_figure_depths_m(ev.cfg)
    panels = []
    lens = ev.designs.get("lens")
    if lens is None:
        lens = OpticalDesign("lens", "lens", build_doe(ev.cfg, "lens"), ev.cfg)
    run_design = ev.designs.get("run") or OpticalDesign("run", "doe", ev.run.doe, ev.cfg)
    panels.append(("lens", lens.doe, lens.bank(depths_m)))
    panels.append(("learned DOE", run_design.doe, run_design.bank(depths_m)))
    for key, design in ev.designs.items():
        if key not in ("lens", "run"):
            panels.append((design.label, design.doe, design.bank(depths_m)))
    ev.figures["psf"] = figures / "eval_psf_lens_vs_doe.png"
    plot_psf_comparison(panels, ev.figures["psf"])

    ev.figures["doe_profile"] = figures / "eval_doe_profile.png"
    plot_doe_profile(ev.run.doe, ev.figures["doe_profile"], samples=ev.cfg.psf.pupil_samples)

    curves = [("doe+net", read_log(ev.run.run_dir / "train_log.csv"))]
    curves += [(method, read_log(run.run_dir / "train_log.csv")) for method, run in ev.baseline_runs.items()]
    if any(rows for _, rows in curves):
        ev.figures["training"] = figures / "eval_training_curves.png"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plot_training_curves(curves, ev.figures["training"])


def write_documents(
    ev,
    title: str = "edofproj evaluation",
    preface: Sequence = (),
    extra: Sequence = (),
    progress: StageProgress | None = None,
) -> dict[str, Path]:
    """Draw the figures (:func:`write_figures`, a ``figures`` stage of ``progress`` when given) and
    write ``summary.md``, ``report.md`` and ``report.html`` into ``ev.out_dir``."""
    if progress is not None:
        progress.start("figures", 1)
    write_figures(ev)
    if progress is not None:
        progress.finish()
    out = Path(ev.out_dir)
    paths = {"summary": out / SUMMARY_NAME, "report_md": out / REPORT_MD_NAME, "report_html": out / REPORT_HTML_NAME}
    summary_report(ev).write(markdown_path=paths["summary"])
    full_report(ev, title, preface, extra).write(markdown_path=paths["report_md"], html_path=paths["report_html"])
    ev.files.update(paths)
    return paths
