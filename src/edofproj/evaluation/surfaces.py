"""``evaluate RUN --surface TEXTURE``: every method over depth on coloured, textured surfaces.

On a flat screen at depth ``z`` whose surface has reflectance ``s`` (a built-in texture or a file
in projector space, :func:`edofproj.data.textures.surface_reflectance`) under an ambient
illuminance ``E`` (``a = s E``: the surface reflects it too), the screen shows
``A(x) = s ⊙ project(x, P_z) + a`` (:mod:`edofproj.imaging.surfaces`). For a held-out test image
``t`` the goal is ``g = f + k t``, the target scaled into what the surface can show
(:func:`edofproj.compensation.achievable.achievable_goal`); every method is given ``g`` and the
camera's view of its uncompensated projection, ``g* = A(g)``, and is scored by SSIM and PSNR of
``A(x)`` against ``g``. The methods, for each base method ``M`` of the run (``lens``, ``doe``,
``doe+net``, ``lens+net`` when its run exists; ``--methods`` chooses):

* ``M`` -- as on a white screen, blind to the texture (``doe+net``: defocus-only);
  for ``lens`` and ``doe``: ``x = g``, nothing compensated;
* ``M+photometric`` -- for ``lens``/``doe`` the photometric-only baseline
  ``x = clip((g - a) / s, 0, 1)`` (:mod:`edofproj.compensation.photometric`: colour and texture,
  no deblurring); for a network, both in cascade: the photometric correction is treated as part
  of the display, and the network deblurs the light it asks for, ``x = net(D, D*)`` with
  ``D = clip((g - a) / s, 0, 1)`` and ``D* = clip((A(D) - a) / s, 0, 1)`` (the camera's view of
  ``D`` projected, divided back: a lab cascade makes that capture);
* ``doe+surface-net`` -- when the run was trained with ``net.surface_input``: its network given the
  surface, ``x = net(g, A(D), s, a)`` (:mod:`edofproj.compensation.surface_net`: its capture is of
  the photometric correction ``D`` projected, as in training).

Writes ``surface_metrics.csv`` (method, surface, depth_mm, image, psnr, ssim, clipped: the
fraction of the goal's pixels out of the surface's range), ``surface_summary.md`` (per surface,
each method's mean and worst-depth SSIM over the score range) and ``figures/eval_surfaces.png``
(:func:`edofproj.reporting.surfaces.plot_surface_figure`: per surface the reflectance, the goal and each method's projection at
the nearest scored depth, and SSIM over depth).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..compensation.achievable import (
    SurfaceRangeWarning,
    achievable_goal,
    clipped_fraction,
    require_visible,
    warn_if_out_of_reach,
)
from ..data import evaluation_images
from ..data.textures import surface_reflectance
from ..errors import EdofprojError
from ..imaging.projection import ScreenProjection
from ..imaging.surfaces import check_illuminance
from ..methods.builder import PreparedMethod
from ..methods.catalogue import select_methods
from ..methods.compensators import score_range_mm
from ..methods.surface_variants import surface_methods
from ..metrics import psnr, ssim
from ..optics.geometry import check_screen_depths_mm
from ..progress import StageProgress
from .pipeline import open_run
from .results import MetricsTable
from .sweep import depth_notes, scored_range_mm, trained_range_mm

SURFACE_METRICS_NAME = "surface_metrics.csv"
SURFACE_SUMMARY_NAME = "surface_summary.md"
SURFACE_FIGURE_NAME = "eval_surfaces.png"
#: Base methods scored by default (``lens+net`` only where its separate run exists).
DEFAULT_BASE_METHODS = ("lens", "doe", "doe+net", "lens+net")


@dataclass
class SurfaceEvaluation:
    out_dir: Path
    run_dir: Path
    surfaces: list[str]
    methods: list[str]
    table: MetricsTable
    range_mm: tuple[float, float]
    ambient: float
    examples: dict = field(default_factory=dict)  # (surface, method) -> display (H, W, 3); (surface, "goal"), ...
    example_depth_mm: float = math.nan
    clipped: dict = field(default_factory=dict)  # surface -> largest fraction of pixels out of range
    notes: list[str] = field(default_factory=list)
    files: dict[str, Path] = field(default_factory=dict)
    seconds: float = math.nan


def evaluate_surfaces(
    run_dir: str | Path,
    surfaces: Sequence[str],
    out_dir: str | Path | None = None,
    images_dir: str | Path | None = None,
    methods: Sequence[str] | None = None,
    depths_mm: Sequence[float] | None = None,
    ambient: float = 0.0,
    baselines_dir: str | Path | None = None,
    overrides: Sequence[str] = (),
    progress: StageProgress | None = None,
    device: str | torch.device = "cpu",
    built: Sequence[PreparedMethod] = (),
) -> SurfaceEvaluation:
    """Score the methods on the textured surfaces (module docstring); files go to ``out_dir`` (default: the run).

    ``surfaces``: built-in texture names or reflectance files the size of the evaluation images;
    ``ambient``: the illuminance ``E >= 0`` (``a = s E``); ``methods``: base methods (default
    :data:`DEFAULT_BASE_METHODS`); ``built``: methods already built from this run
    (:meth:`~edofproj.methods.builder.MethodBuilder.build_all`)."""
    clock = time.perf_counter()
    ambient = check_illuminance(ambient, "--ambient")
    if not surfaces:
        raise EdofprojError("--surface needs at least one texture")
    opened = open_run(run_dir, out_dir, overrides)
    cfg = opened.cfg
    progress = progress or StageProgress("evaluate", enabled=False)
    images = evaluation_images(cfg, images_dir)
    height, width = (int(v) for v in images[0][1].shape[-2:])
    textures = {str(name): surface_reflectance(name, (height, width)).to(device) for name in dict.fromkeys(surfaces)}
    for name, rho in textures.items():  # before any work: a surface that shows nothing would score SSIM 1
        require_visible(rho, rho * ambient, f"surface '{name}'" + (f" under ambient {ambient:g}" if ambient else ""))
    depths = check_screen_depths_mm(depths_mm if depths_mm is not None else cfg.evaluation.depths_mm, "--depths-mm")
    range_mm = scored_range_mm(depths.tolist(), score_range_mm(cfg))  # what the summary covers, in its headings

    explicit = methods is not None
    specs = select_methods(list(methods) if methods is not None else list(DEFAULT_BASE_METHODS))
    builder = opened.method_builder(baselines_dir, explicit, device)
    progress.start("preparing methods", len(specs))
    prepared = builder.build_all(specs, progress, built)
    chosen = surface_methods(prepared, opened.run.net)

    table = MetricsTable(("method", "surface", "depth_mm", "image"), ("psnr", "ssim", "clipped"))
    evaluation = SurfaceEvaluation(
        opened.out_dir, opened.run_path, list(textures), [m.name for m in chosen], table, range_mm, float(ambient)
    )
    evaluation.notes = list(builder.notes)
    if depths_mm is not None:
        evaluation.notes += depth_notes(depths.tolist(), trained_range_mm(cfg), score_range_mm(cfg))
    in_range = depths[(depths >= range_mm[0] - 1e-9) & (depths <= range_mm[1] + 1e-9)]
    evaluation.example_depth_mm = float(in_range.min() if in_range.size else depths.min())
    progress.start(
        "surfaces",
        len(textures) * len(images) * depths.size,
        detail=f"{len(textures)} surfaces x {len(chosen)} methods at {height}x{width}",
    )
    with torch.inference_mode():
        for surface_name, rho in textures.items():
            amb = rho * float(ambient)
            for image_index, (image_name, image) in enumerate(images):
                target = image[None].to(device)
                goal = achievable_goal(target, rho, amb)
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", SurfaceRangeWarning)  # one note per surface, not one per image
                    clipped = warn_if_out_of_reach(goal, rho, amb, what=f"image '{image_name}'")
                if caught and surface_name not in evaluation.clipped:
                    evaluation.notes.append(f"surface '{surface_name}': {caught[0].message}")
                evaluation.clipped[surface_name] = max(evaluation.clipped.get(surface_name, 0.0), clipped)
                if image_index == 0:
                    evaluation.examples[(surface_name, "goal")] = _hwc(goal.image)
                    evaluation.examples[(surface_name, "reflectance")] = _hwc(rho)
                for depth_mm in depths:
                    _score_depth(
                        evaluation, chosen, surface_name, image_name, image_index, goal.image, rho, amb, depth_mm
                    )
                    progress.advance(1, detail=f"{surface_name} {depth_mm:g} mm")
    progress.finish()
    write_surface_metrics(evaluation)
    evaluation.seconds = time.perf_counter() - clock
    return evaluation


def _hwc(image: torch.Tensor) -> np.ndarray:
    return image[0].clamp(0, 1).permute(1, 2, 0).cpu().numpy()


def _score_depth(evaluation, chosen, surface_name, image_name, image_index, goal, rho, amb, depth_mm) -> None:
    depth_m = np.array([depth_mm * 1e-3])
    clipped = float(clipped_fraction(goal, rho, amb)[0])
    captured_by_design: dict[str, torch.Tensor] = {}
    screens: dict[str, ScreenProjection] = {}
    for method in chosen:
        design = method.design
        psf = design.psf(depth_m)  # type: ignore[attr-defined]
        key = design.key  # type: ignore[attr-defined]
        if key not in screens:
            screens[key] = ScreenProjection(psf)
            captured_by_design[key] = rho * screens[key](goal) + amb
        projection = screens[key]

        def screen(image: torch.Tensor) -> torch.Tensor:
            return rho * projection(image) + amb

        x = method.compensate(goal, captured_by_design[key], psf, rho, amb, screen)
        display = screen(x)
        evaluation.table.add(
            method=method.name,
            surface=surface_name,
            depth_mm=float(depth_mm),
            image=image_name,
            psnr=float(psnr(display.clamp(0, 1), goal)[0]),
            ssim=float(ssim(display.clamp(0, 1), goal)[0]),
            clipped=clipped,
        )
        if image_index == 0 and abs(depth_mm - evaluation.example_depth_mm) < 1e-9:
            evaluation.examples[(surface_name, method.name)] = _hwc(display)


def surface_table(evaluation: SurfaceEvaluation, surface: str) -> MetricsTable:
    """The rows of one surface (for :meth:`MetricsTable.range_stats`)."""
    rows = [r for r in evaluation.table.rows if r["surface"] == surface]
    return MetricsTable(evaluation.table.keys, evaluation.table.metrics, rows)


def write_surface_metrics(evaluation: SurfaceEvaluation) -> None:
    """``surface_metrics.csv`` (every score) in the evaluation's output folder; the summary and the
    figure are written by :func:`edofproj.reporting.surfaces.write_surface_report`."""
    out = evaluation.out_dir
    out.mkdir(parents=True, exist_ok=True)
    evaluation.files["metrics"] = out / SURFACE_METRICS_NAME
    evaluation.table.write_csv(evaluation.files["metrics"])
