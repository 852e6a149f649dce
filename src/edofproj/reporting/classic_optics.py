"""The files of ``edofproj tune-classic``: the table, the plot and the chosen value of a classic element's sweep.

``classic_sweep.csv`` holds every score (candidate, depth, validation image); ``classic_sweep.md``
the table per candidate (mean SSIM over the depths and the worst depth, the tuned NSR) with the
chosen candidate and the configuration's own value marked; ``classic_sweep.png`` the mean and
worst-depth SSIM against the parameter (:class:`~edofproj.evaluation.classic_optics.ClassicSweep`).
"""

from __future__ import annotations

from pathlib import Path

from ..evaluation.classic_optics import ClassicSweep
from ..fileio import atomic_path, write_text_atomic

SWEEP_TABLE_NAME = "classic_sweep.csv"
SWEEP_SUMMARY_NAME = "classic_sweep.md"
SWEEP_FIGURE_NAME = "classic_sweep.png"
AXIS_LABELS = {
    "cubic": "cubic strength alpha (waves)",
    "axicon": "focal-line length far - near (mm)",
    "multifocal": "number of foci",
}


def sweep_markdown(sweep: ClassicSweep, current: str, command: str) -> str:
    """The table of every candidate, the chosen one and how far it is from the configuration's own."""
    chosen = sweep.chosen
    lines = [
        f"# {sweep.kind}: parameters tuned by the blind depth-ensemble filter",
        "",
        f"Scored: `{sweep.kind}+ensemble` (its depth-ensemble Wiener filter, NSR tuned on training crops) on "
        f"{len(sweep.image_names)} validation images at {', '.join(f'{z:g}' for z in sweep.depths_mm)} mm; "
        "SSIM averaged over the images at each depth, then the mean over the depths and the worst depth.",
        "",
        "| candidate | mean SSIM | worst SSIM (depth mm) | NSR | |",
        "| --- | ---: | ---: | ---: | --- |",
    ]
    for candidate in sweep.candidates:
        mean, worst, depth = sweep.summary[candidate.label]
        marks = []
        if candidate.label == chosen.label:
            marks.append("**chosen**")
        if candidate.label == current:
            marks.append("the configuration's value")
        lines.append(
            f"| {candidate.label} | {mean:.4f} | {worst:.4f} ({depth:g}) | {sweep.nsr[candidate.label]:.3g} | "
            f"{', '.join(marks)} |"
        )
    mean_chosen = sweep.summary[chosen.label][0]
    lines += ["", f"Chosen: **{chosen.label}** (`--set {' --set '.join(chosen.overrides)}`)."]
    if sweep.chosen_at_edge:
        lines.append(
            "The chosen candidate lies at an end of the swept parameter: the best value may lie beyond it "
            "(extend `--values`)."
        )
    if current in sweep.summary and current != chosen.label:
        lines.append(
            f"The configuration's value, {current}, scores {sweep.summary[current][0]:.4f}: "
            f"{mean_chosen - sweep.summary[current][0]:.4f} below the chosen one."
        )
    elif current not in sweep.summary:
        lines.append(f"The configuration's value, {current}, was not among the candidates.")
    lines += ["", "Command:", "", f"    {command}", ""]
    return "\n".join(lines)


def plot_sweep(sweep: ClassicSweep, path: str | Path, current: str) -> None:
    """Mean and worst-depth SSIM against the candidate's parameter; the chosen candidate ringed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = sorted(sweep.candidates, key=lambda c: c.value)
    x = [c.value for c in order]
    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    ax.plot(x, [sweep.summary[c.label][0] for c in order], "o-", color="C0", label="mean over depths")
    ax.plot(x, [sweep.summary[c.label][1] for c in order], "s--", color="C3", label="worst depth")
    chosen = sweep.chosen
    ax.plot([chosen.value], [sweep.summary[chosen.label][0]], "o", ms=14, mfc="none", color="k", label="chosen")
    for candidate in order:
        if candidate.label == current:
            ax.axvline(candidate.value, color="0.6", lw=1, ls=":", label="configuration's value")
        if sweep.kind != "cubic":
            ax.annotate(candidate.label, (candidate.value, sweep.summary[candidate.label][1]), fontsize=7)
    ax.set_xlabel(AXIS_LABELS[sweep.kind])
    ax.set_ylabel(f"SSIM of {sweep.kind}+ensemble")
    ax.set_title(f"{sweep.kind}: blind depth-ensemble filter on validation images", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def write_sweep(sweep: ClassicSweep, out_dir: str | Path, current: str, command: str) -> dict[str, Path]:
    """The three files of the sweep in ``out_dir`` (each written atomically); returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"table": out / SWEEP_TABLE_NAME, "summary": out / SWEEP_SUMMARY_NAME, "figure": out / SWEEP_FIGURE_NAME}
    sweep.table.write_csv(files["table"])
    write_text_atomic(files["summary"], sweep_markdown(sweep, current, command))
    plot_sweep(sweep, files["figure"], current)
    return files
