"""Running the methods: the flat-screen depth sweep and the tilted screen, scored per image.

Both run the closed loop of :mod:`edofproj.compensation.closed_loop` (the forward models clamp
``x`` to ``[0, 1]``). Flat screen at depth ``z`` (each method's design PSF ``p_z``; see :mod:`.methods`)::

    I* = project(I, p_z),   x = compensate(I, I*, p_z),   display = project(x, p_z)

Tilted screen (paper Sec. 5.3): a plane turned by ``evaluation.tilt_deg`` about the vertical
axis whose depth runs from the near end of ``evaluation.tilt_range_mm`` (left column) to its far end
(right column; ``[]``: the scored range, :func:`tilted_range_mm`), ``1/z`` affine across the columns
(:func:`edofproj.imaging.screens.tilted_plane_depth_map`). The projection of an image ``x`` on
it is rendered by depth layers, ``render(x)`` (:func:`edofproj.imaging.depth_layers.render_depth_map`,
``imaging.depth_layers`` layers evenly spaced in ``1/z``), so::

    I* = render(I),   x = compensate(I, I*, p_c),   display = render(x)

The networks get the tilted capture ``I*``, as they would from a camera. Wiener and CLS need
one PSF: they get ``p_c``, the PSF at the depth of the screen's middle column
(``1/z_c = (1/near + 1/far) / 2``) -- a spatially invariant deconvolution, which is what those
methods can do on a screen whose blur varies across the image.

The work is split into tasks, one per depth, batch of images and optical design (the methods of a
design share its uncompensated capture), run ``workers`` at a time (:mod:`edofproj.cpu_tasks`: on
a 2-core CPU two tasks of one intra-op thread each, which keep both cores busy where one method at
a time on two threads leaves them idle between its many small operations). A task's scores do not
depend on the number of workers, only on the intra-op threads each is given.

Scores per image: PSNR, SSIM, MS-SSIM, the CIEDE2000 colour difference (mean and 95th percentile),
the SSIM of each colour channel (:mod:`edofproj.metrics`) and the perceptual metrics whose weights
are present (LPIPS with AlexNet, DISTS).

The depths scored are stated: :func:`scored_range_mm` is the range the tables' means and worst
depths cover (the score range ``evaluation.score_range_mm`` met by the depths asked for; all of
them when none lies in it), and :func:`depth_notes` names the depths outside the score range and
outside the range the run was trained on (``psf.depth_min_mm``-``psf.depth_max_mm``).
"""

from __future__ import annotations

from collections import OrderedDict
from functools import partial
from typing import Callable, Sequence

import numpy as np
import torch

from .. import metrics
from ..compensation.closed_loop import closed_loop, flat_screen
from ..config import M_PER_MM
from ..cpu_tasks import default_workers, run_tasks
from ..imaging.depth_layers import layer_depths_m, render_depth_map
from ..imaging.screens import tilted_plane_depth_map
from ..methods.compensators import score_range_mm
from ..methods.depth_ranges import depth_notes, scored_range_mm, trained_range_mm  # noqa: F401 (re-exported)
from .results import BASE_METRICS, MetricsTable

Progress = Callable[[int], None]
"""``progress(units_done)``: called after each method has run on a batch, with the number of images."""

#: Images of the same size evaluated together (one batch through each method).
MAX_BATCH = 8
#: Perceptual metrics reported when their weights are present: column name -> metric name.
PERCEPTUAL_COLUMNS = {"lpips": "lpips-alex", "dists": "dists"}


def load_perceptual_metrics(weights_dir=None) -> dict:
    """The perceptual metric objects that can be built here, by column name (``{}`` when none)."""
    available = metrics.available_perceptual_metrics(weights_dir)
    loaded = {}
    for column, name in PERCEPTUAL_COLUMNS.items():
        if available.get(name):
            try:
                loaded[column] = metrics.perceptual_metric(name, weights_dir).eval()
            except metrics.PerceptualWeightsMissing:
                continue
    return loaded


def score(
    display: torch.Tensor, target: torch.Tensor, perceptual: dict, scorer: metrics.ImageScorer | None = None
) -> list[dict[str, float]]:
    """Metrics of each displayed image of a batch ``(B, 3, H, W)`` against its target: ``B`` dicts.
    ``scorer``: :class:`~edofproj.metrics.ImageScorer` of ``target``, when several displays are scored against it."""
    columns = (scorer or metrics.ImageScorer(target)).scores(display)
    for column, metric in perceptual.items():
        columns[column] = metric(display, target)
    return [{name: float(values[i]) for name, values in columns.items()} for i in range(display.shape[0])]


def metric_columns(perceptual: dict) -> tuple[str, ...]:
    return BASE_METRICS + tuple(c for c in PERCEPTUAL_COLUMNS if c in perceptual)


def _with_psf(compensate, psf: torch.Tensor):
    """A method's ``compensate(target, captured, psf)`` with the PSF it is told, as ``(target, captured) -> x``."""
    return lambda target, captured: compensate(target, captured, psf)


def _by_design(methods) -> "OrderedDict[str, list]":
    groups: OrderedDict[str, list] = OrderedDict()
    for method in methods:
        groups.setdefault(method.design.key, []).append(method)
    return groups


def _closed_loop_displays(group, target: torch.Tensor, forward, captured: torch.Tensor, psf: torch.Tensor):
    """Yield ``(method, display)`` for the methods of one optical design on one screen: each compensates
    ``target`` from the same uncompensated capture ``captured = forward(target)``, told the PSF ``psf``,
    and its input is shown through ``forward`` (:func:`edofproj.compensation.closed_loop.closed_loop`)."""
    for method in group:
        loop = closed_loop(target, forward, _with_psf(method.compensate, psf), captured=captured)
        yield method, loop.projected


def image_batches(images: Sequence[tuple[str, torch.Tensor]], max_batch: int = MAX_BATCH):
    """``[(names, (B, 3, H, W))]``: consecutive images of the same size stacked (at most ``max_batch``)."""
    batches: list[tuple[list[str], list[torch.Tensor]]] = []
    for name, image in images:
        if batches and batches[-1][1][0].shape == image.shape and len(batches[-1][0]) < max_batch:
            batches[-1][0].append(name)
            batches[-1][1].append(image)
        else:
            batches.append(([name], [image]))
    return [(names, torch.stack(stack)) for names, stack in batches]


def flat_screen_displays(methods, target: torch.Tensor, depth_mm: float):
    """Yield ``(method, display)`` for every method at one depth; ``target`` and ``display`` ``(B, 3, H, W)``."""
    for group in _by_design(methods).values():
        yield from _flat_screen_group(group, target, depth_mm)


def _flat_screen_group(group, target: torch.Tensor, depth_mm: float):
    """Yield ``(method, display)`` for the methods of one design at one depth."""
    psf = group[0].design.psf([depth_mm * M_PER_MM])
    forward = flat_screen(psf)
    yield from _closed_loop_displays(group, target, forward, forward(target), psf)


def flat_screen_sweep(
    methods,
    images: Sequence[tuple[str, torch.Tensor]],
    depths_mm: Sequence[float],
    perceptual: dict,
    progress: Progress | None = None,
    device: str | torch.device = "cpu",
    workers: int | None = None,
) -> MetricsTable:
    """Score every method on every image at every depth (rows: method, depth_mm, image); the images
    are moved to ``device``, where the methods' networks and PSFs must be. ``workers``: tasks at once
    (module docstring; default :func:`~edofproj.cpu_tasks.default_workers`)."""
    table = MetricsTable(("method", "depth_mm", "image"), metric_columns(perceptual))
    batches = [(names, target.to(device)) for names, target in image_batches(images)]
    scorers = [metrics.ImageScorer(target) for _, target in batches]

    def task(group, target, scorer, depth_mm):
        return lambda: [
            (m.name, score(display, target, perceptual, scorer))
            for m, display in _flat_screen_group(group, target, depth_mm)
        ]

    keys, tasks = [], []
    for depth_mm in depths_mm:
        for (names, target), scorer in zip(batches, scorers):
            for group in _by_design(methods).values():
                keys.append((float(depth_mm), names))
                tasks.append(task(group, target, scorer, depth_mm))
    for (depth_mm, names), scored in zip(keys, run_tasks(tasks, workers or default_workers(device))):
        for method_name, values_of_images in scored:
            for name, values in zip(names, values_of_images):
                table.add(method=method_name, depth_mm=depth_mm, image=name, **values)
            if progress is not None:
                progress(len(names))
    order = {m.name: i for i, m in enumerate(methods)}
    names_order = {name: i for i, (name, _) in enumerate(images)}
    table.rows.sort(key=lambda r: (r["depth_mm"], order[r["method"]], names_order[r["image"]]))
    return table


def nearest_scored_depths_mm(wanted_mm: Sequence[float], scored_mm: Sequence[float]) -> list[float]:
    """Each depth of ``wanted_mm`` (the comparison figure's rows, ``evaluation.comparison_depths_mm``)
    replaced by the nearest depth of the sweep, ``scored_mm`` (repeats dropped, order kept): the figure
    then shows depths whose scores are in the tables."""
    rows: list[float] = []
    for z in wanted_mm:
        nearest = float(min(scored_mm, key=lambda s: (abs(float(s) - float(z)), float(s))))
        if nearest not in rows:
            rows.append(nearest)
    return rows


def example_displays(
    methods, image: torch.Tensor, depths_mm: Sequence[float], perceptual: dict, device: str | torch.device = "cpu"
) -> dict:
    """``{(depth_mm, method name): (display (H, W, 3) array, scores)}`` for the comparison figure."""
    examples = {}
    target = image.unsqueeze(0).to(device)
    with torch.inference_mode():
        scorer = metrics.ImageScorer(target)
        for depth_mm in depths_mm:
            for method, display in flat_screen_displays(methods, target, depth_mm):
                examples[(float(depth_mm), method.name)] = (
                    _to_array(display),
                    score(display, target, perceptual, scorer)[0],
                )
    return examples


# --------------------------------------------------------------------------- tilted screen


def tilted_range_mm(cfg) -> tuple[float, float]:
    """``(near, far)`` depths (mm) of the tilted screen: ``evaluation.tilt_range_mm``, or the scored range
    (:func:`edofproj.methods.compensators.score_range_mm`) when that is empty."""
    if cfg.evaluation.tilt_range_mm:
        near, far = cfg.evaluation.tilt_range_mm
        return float(near), float(far)
    return score_range_mm(cfg)


class TiltedScreen:
    """The tilted plane of the module docstring for images of ``height x width`` pixels."""

    def __init__(self, cfg, height: int, width: int) -> None:
        ev = cfg.evaluation
        near_mm, far_mm = tilted_range_mm(cfg)
        self.near_m, self.far_m = near_mm * 1e-3, far_mm * 1e-3
        self.tilt_deg = float(ev.tilt_deg)
        self.depth_map_m = tilted_plane_depth_map(height, width, self.tilt_deg, self.near_m, self.far_m)
        self.layers_m = layer_depths_m(self.near_m, self.far_m, cfg.imaging.depth_layers)
        self.centre_m = 2.0 / (1.0 / self.near_m + 1.0 / self.far_m)

    def render(self, x: torch.Tensor, design) -> torch.Tensor:
        """What the tilted screen shows when the projector (with ``design``) emits ``x``."""
        return render_depth_map(x, self.depth_map_m, design.psf(self.layers_m), layers=self.layers_m)

    def displays(self, methods, target: torch.Tensor):
        """Yield ``(method, display)`` on this screen for every method; ``target`` ``(B, 3, H, W)``."""
        for group in _by_design(methods).values():
            yield from self.group_displays(group, target)

    def group_displays(self, group, target: torch.Tensor):
        """Yield ``(method, display)`` on this screen for the methods of one design."""
        design = group[0].design
        forward = partial(self.render, design=design)
        captured = forward(target)
        centre_psf = design.psf([self.centre_m])
        yield from _closed_loop_displays(group, target, forward, captured, centre_psf)


def tilted_screen_sweep(
    methods,
    images: Sequence[tuple[str, torch.Tensor]],
    cfg,
    perceptual: dict,
    progress: Progress | None = None,
    device: str | torch.device = "cpu",
    workers: int | None = None,
) -> tuple[MetricsTable, dict]:
    """Score every method on the tilted screen. Returns the table (rows: method, near_mm,
    far_mm, image) and the displays of the first image ``{method name: (array, scores)}``.
    ``workers``: tasks at once (module docstring; default :func:`~edofproj.cpu_tasks.default_workers`)."""
    table = MetricsTable(("method", "near_mm", "far_mm", "image"), metric_columns(perceptual))
    examples = {}
    screens: dict[tuple[int, int], TiltedScreen] = {}
    first = images[0][0]

    def task(screen, group, target, scorer, names):
        def run():
            scored = []
            for method, display in screen.group_displays(group, target):
                example = _to_array(display[names.index(first) : names.index(first) + 1]) if first in names else None
                scored.append((method.name, score(display, target, perceptual, scorer), example))
            return scored

        return run

    keys, tasks = [], []
    for names, target in image_batches(images):
        target = target.to(device)
        size = tuple(target.shape[-2:])
        screen = screens.setdefault(size, TiltedScreen(cfg, *size))
        scorer = metrics.ImageScorer(target)
        for group in _by_design(methods).values():
            keys.append((screen, names))
            tasks.append(task(screen, group, target, scorer, names))
    for (screen, names), scored in zip(keys, run_tasks(tasks, workers or default_workers(device))):
        for method_name, values_of_images, example in scored:
            for name, values in zip(names, values_of_images):
                table.add(
                    method=method_name, near_mm=screen.near_m * 1e3, far_mm=screen.far_m * 1e3, image=name, **values
                )
                if name == first:
                    examples[method_name] = (example, values)
            if progress is not None:
                progress(len(names))
    return table, examples


def _to_array(image: torch.Tensor) -> np.ndarray:
    """The first image of a batch as an ``(H, W, 3)`` array in ``[0, 1]``."""
    return image[0].clamp(0, 1).permute(1, 2, 0).cpu().numpy()
