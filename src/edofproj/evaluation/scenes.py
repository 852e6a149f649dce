"""``evaluate RUN --scene S``: every method on 3-D scenes, scored over the objects' pixels.

For a scene seen by the projector (ray cast, :mod:`edofproj.scenes`) with hit mask ``m`` and a
target image ``I`` the size of the projector's panel (``optics.height_px x optics.width_px``,
the test images scaled to cover it, so the scene fills the view as designed), every method goes
through the scene renderer ``R`` (:func:`edofproj.scenes.render_scene`, ``imaging.depth_layers``
layers over the depths seen):

    I*      = R(I)                                  the uncompensated projection
    x       = compensate(I, I*, p_c)                the projector input
    display = R(clamp(x, 0, 1))                     what the objects show

The networks are blind as on flat screens; Wiener and CLS are given one PSF, ``p_c`` at the
centre in ``1/z`` of the depths seen (a compensation that knows the depth map per pixel is not
among the methods). Scores are taken over the object's pixels only: PSNR of ``m display``
against ``m I`` over ``m``, and the mean of the local SSIM map (:func:`edofproj.metrics.ssim_map`)
over the pixels of ``m`` where the SSIM window fits.

Writes ``scene_metrics.csv`` (method, scene, image, psnr, ssim); the figures and
``scene_summary.md`` are :func:`edofproj.reporting.scenes.write_scene_report`'s.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..config import apply_overrides
from ..cpu_tasks import default_workers, run_tasks
from ..data import evaluation_images
from ..errors import EdofprojError
from ..methods.builder import PreparedMethod
from ..methods.catalogue import select_methods
from ..methods.designs import OpticalDesign
from ..metrics import ssim_map
from ..optics.geometry import ProjectorGeometry
from ..progress import StageProgress
from ..scenes import BUILTIN_SCENES, cast_scene, check_scene_depth_range, load_scene, render_scene
from ..scenes.render import scene_layers_m
from .pipeline import open_run
from .results import MetricsTable

SCENE_METRICS_NAME = "scene_metrics.csv"
ALL_BUILTIN = "builtin"


@dataclass
class SceneEvaluation:
    out_dir: Path
    run_dir: Path
    scenes: list[str]
    methods: list[str]
    table: MetricsTable
    depth_ranges_mm: dict[str, tuple[float, float]]
    examples: dict = field(default_factory=dict)  # (scene, method) -> (display (H, W, 3), ssim map (H, W), scores)
    targets: dict = field(default_factory=dict)  # scene -> masked target (H, W, 3)
    notes: list[str] = field(default_factory=list)
    files: dict[str, Path] = field(default_factory=dict)
    seconds: float = math.nan


def masked_scores(display: torch.Tensor, target: torch.Tensor, hit: torch.Tensor) -> tuple[list[dict], torch.Tensor]:
    """PSNR and SSIM over the hit pixels for each image of ``(B, 3, H, W)``, and the SSIM maps ``(B, H, W)``
    (NaN off the object). ``hit`` ``(H, W)`` bool."""
    mask = hit.to(display.dtype)
    masked_target = target * mask
    squared = ((display - masked_target) ** 2 * mask).sum((1, 2, 3)) / (3 * mask.sum())
    psnr = 10 * torch.log10(1.0 / squared.clamp_min(1e-12))
    local = ssim_map(display, masked_target)
    local = torch.where(hit[None], local, torch.full_like(local, float("nan")))
    ssim = local.nanmean((1, 2))
    return [{"psnr": float(p), "ssim": float(s)} for p, s in zip(psnr, ssim)], local


def resolve_scene_names(names: Sequence[str]) -> list[str]:
    """Expand ``builtin`` to every built-in scene; keep the rest (names or files) in order."""
    resolved: list[str] = []
    for name in names:
        for item in list(BUILTIN_SCENES) if name == ALL_BUILTIN else [name]:
            if item not in resolved:
                resolved.append(item)
    if not resolved:
        raise EdofprojError("--scene needs at least one scene")
    return resolved


def evaluate_scenes(
    run_dir: str | Path,
    scene_names: Sequence[str],
    out_dir: str | Path | None = None,
    images_dir: str | Path | None = None,
    methods: Sequence[str] | None = None,
    baselines_dir: str | Path | None = None,
    overrides: Sequence[str] = (),
    progress: StageProgress | None = None,
    device: str | torch.device = "cpu",
    built: Sequence[PreparedMethod] = (),
) -> SceneEvaluation:
    """Score the run's methods on the scenes (module docstring); files go to ``out_dir`` (default: the run).
    ``built``: methods already built from this run (:meth:`~edofproj.methods.builder.MethodBuilder.build_all`)."""
    clock = time.perf_counter()
    specs = select_methods(methods)
    opened = open_run(run_dir, out_dir, overrides)
    cfg = opened.cfg
    progress = progress or StageProgress("evaluate", enabled=False)
    geometry = ProjectorGeometry.from_config(cfg.optics)
    height, width = geometry.height_px, geometry.width_px
    near_m, far_m = cfg.psf.depth_min_m, cfg.psf.depth_max_m

    names = resolve_scene_names(scene_names)
    casts = {}
    for name in names:
        scene = load_scene(name, geometry)
        cast = cast_scene(scene, height, width, geometry)
        check_scene_depth_range(
            cast, near_m, far_m, f"the run's PSFs (psf.depth_min_mm-psf.depth_max_mm) for scene '{scene.name}'"
        )
        casts[scene.name] = cast
    sized = apply_overrides(cfg, [f"evaluation.image_size=[{height},{width}]"])
    images = evaluation_images(sized, images_dir, enlarge=True)  # a picture fills the projector frame

    builder = opened.method_builder(baselines_dir, bool(methods), device)
    progress.start("preparing methods", len(specs))
    prepared = builder.build_all(specs, progress, built)

    table = MetricsTable(("method", "scene", "image"), ("psnr", "ssim"))
    evaluation = SceneEvaluation(opened.out_dir, opened.run_path, list(casts), [m.name for m in prepared], table, {})
    evaluation.notes = list(builder.notes)
    progress.start(
        "scenes", len(casts) * len(images) * len(prepared), detail=f"{len(casts)} scenes at {height}x{width}"
    )
    for scene_name, cast in casts.items():
        lo, hi = cast.depth_range_m()
        evaluation.depth_ranges_mm[scene_name] = (lo * 1e3, hi * 1e3)
        layers = scene_layers_m(cast, cfg.imaging.depth_layers)
        centre = np.array([2.0 / (1.0 / lo + 1.0 / hi)])
        hit = torch.as_tensor(cast.hit, device=device)
        for image_index, (image_name, image) in enumerate(images):
            target = image[None].to(device)
            if image_index == 0:
                evaluation.targets[scene_name] = (target * hit)[0].permute(1, 2, 0).cpu().numpy()
            designs: dict[str, OpticalDesign] = {m.design.key: m.design for m in prepared}
            with torch.inference_mode():  # each design's capture and PSFs, before the methods share them
                captured = {key: render_scene(target, cast, d.psf(layers), layers) for key, d in designs.items()}
                for design in designs.values():
                    design.psf(centre)

            def shown(method, target=target, captured=captured, cast=cast, layers=layers, centre=centre, hit=hit):
                design = method.design
                x = method.compensate(target, captured[design.key], design.psf(centre))
                display = render_scene(x, cast, design.psf(layers), layers)
                return (*masked_scores(display, target, hit), display)

            # one task per method on the CPU's cores (edofproj.cpu_tasks), results in the methods' order
            tasks = [partial(shown, method) for method in prepared]
            for method, (scores, local, display) in zip(prepared, run_tasks(tasks, default_workers(device))):
                table.add(method=method.name, scene=scene_name, image=image_name, **scores[0])
                if image_index == 0:
                    evaluation.examples[(scene_name, method.name)] = (
                        display[0].clamp(0, 1).permute(1, 2, 0).cpu().numpy(),
                        local[0].cpu().numpy(),
                        scores[0],
                    )
                progress.advance(1, detail=f"{scene_name} {method.name}")
    progress.finish()
    write_scene_files(evaluation)
    evaluation.seconds = time.perf_counter() - clock
    return evaluation


def write_scene_files(evaluation: SceneEvaluation) -> None:
    """``scene_metrics.csv`` in the output directory (its path in ``evaluation.files["metrics"]``)."""
    out = evaluation.out_dir
    out.mkdir(parents=True, exist_ok=True)
    evaluation.files["metrics"] = out / SCENE_METRICS_NAME
    evaluation.table.write_csv(evaluation.files["metrics"])
