"""Validation during training: the network against the linear filter of the current DOE.

Every ``train.validate_every`` steps (and after the last one) the network is scored on
``train.validation_images`` held-back images -- the colour classes of the validation set
(:data:`~edofproj.data.validation.COLOUR_CLASSES`: a near-empty primary, saturated colours, a dark
and a high-key scene, a fine grating, flat graphics; never training or test images), centre crops of
``data.crop`` pixels -- at three flat-screen depths (the ends and the middle in ``1/z`` of the
scored range). For each image it compares, as means over the depths,

    SSIM and CIEDE2000 of  project(net(I, I*))   and of   project(E(I))

where ``E`` is the depth-ensemble linear filter of the DOE as it is at that step
(:mod:`.linear_filter`). The results go to ``validation_log.csv`` (``step, ssim_net, ssim_linear,
de2000_net, de2000_linear, behind, worst_image, worst_difference``: means over the images, the
number of images where the network's SSIM is below the filter's by more than
:data:`BEHIND_TOLERANCE`, and the image where the network
is furthest behind) and, when the network is behind on any image, to a line on the terminal.

:class:`StepChecks` is the trainer's one hook: it also recomputes a safe network's base filter
(:func:`~.linear_filter.refresh_linear_base`).
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import nn

from ..compensation.closed_loop import closed_loop, flat_screen
from ..compensation.linear_base import LinearBase
from ..config import Config
from ..data.validation import COLOUR_CLASSES, validation_images
from ..errors import BlurExceedsWindowWarning
from ..fileio import write_text_atomic
from ..metrics import delta_e2000, ssim
from .linear_filter import current_linear_filter, refresh_due, refresh_linear_base, scored_range_m
from .psf_table import DepthPSFTable

VALIDATION_LOG = "validation_log.csv"
#: SSIM below the linear filter's by more than this counts as behind (smaller: rounding).
BEHIND_TOLERANCE = 1e-4
COLUMNS = (
    "step",
    "ssim_net",
    "ssim_linear",
    "de2000_net",
    "de2000_linear",
    "behind",
    "worst_image",
    "worst_difference",
)


def validation_depths_m(cfg: Config) -> np.ndarray:
    """Near end, middle in ``1/z`` and far end of the scored range (m)."""
    near, far = scored_range_m(cfg)
    return 1.0 / np.linspace(1.0 / near, 1.0 / far, 3)


@torch.no_grad()
def compare_with_linear_filter(
    cfg: Config, net: nn.Module, psf_source: nn.Module, images: torch.Tensor
) -> dict[str, np.ndarray]:
    """Per image ``(N,)`` arrays, means over :func:`validation_depths_m`: ``ssim_net``, ``ssim_linear``,
    ``de2000_net``, ``de2000_linear`` (module docstring). ``images`` ``(N, 3, H, W)``."""
    was_training = net.training
    net.eval()
    own = getattr(net, "linear_base", None)
    linear: LinearBase = own if isinstance(own, LinearBase) else current_linear_filter(cfg, psf_source)
    linear = linear.to(images.device)
    sums = {key: np.zeros(images.shape[0]) for key in ("ssim_net", "ssim_linear", "de2000_net", "de2000_linear")}
    depths = validation_depths_m(cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BlurExceedsWindowWarning)
        for depth in depths:
            forward = flat_screen(psf_source(np.array([depth])).to(images.device))
            captured = forward(images)
            for name, compensate in (("net", net), ("linear", lambda target, _: linear(target))):
                display = closed_loop(images, forward, compensate, captured=captured).projected
                sums[f"ssim_{name}"] += ssim(display, images).cpu().numpy()
                sums[f"de2000_{name}"] += delta_e2000(display, images)[0].numpy()
    net.train(was_training)
    return {key: value / len(depths) for key, value in sums.items()}


class StepChecks:
    """The trainer's hook: refreshes a safe network's linear base filter and validates (module docstring).

    ``start(step)`` before the first step of a session, ``after_step(step)`` after each step
    (before that step's checkpoint); steps are the phase's, the log's the run's (``offset`` before them). Only the process with ``writes=True`` validates and writes."""

    def __init__(
        self, cfg: Config, net: nn.Module, psf_source: nn.Module, run_dir: Path, writes: bool, device, offset: int = 0
    ):
        self.cfg = cfg
        self.offset = offset  # the run's step before the first of this phase: the log counts the run's steps
        self.net = net
        self.psf_source = psf_source
        self.path = Path(run_dir) / VALIDATION_LOG
        self.writes = writes
        self.images: list[tuple[str, torch.Tensor]] = []
        if writes and cfg.train.validate_every > 0:
            size = (cfg.data.crop, cfg.data.crop)
            names = COLOUR_CLASSES[: cfg.train.validation_images]
            self.images = [(n, im.to(device)) for n, im in validation_images(size, names=names)]

    def start(self, step: int, resumed: bool) -> None:
        if not resumed:  # a resumed run's checkpoint holds its filter
            refresh_linear_base(self.cfg, self.net, self.psf_source)
        if self.writes and self.images:
            self._truncate_after(self.offset + step)

    def after_step(self, step: int, say: Callable[[str], None] = print) -> None:
        # a fixed DOE's filter never changes: set once by start() (or held by the resumed checkpoint)
        if not isinstance(self.psf_source, DepthPSFTable) and refresh_due(self.cfg, step):
            refresh_linear_base(self.cfg, self.net, self.psf_source)
        every = self.cfg.train.validate_every
        if self.images and (step % every == 0 or step == self.cfg.train.steps):
            self.validate(step, say)

    def validate(self, step: int, say: Callable[[str], None] = print) -> dict:
        names = [n for n, _ in self.images]
        scores = compare_with_linear_filter(
            self.cfg, self.net, self.psf_source, torch.stack([i for _, i in self.images])
        )
        difference = scores["ssim_net"] - scores["ssim_linear"]
        worst = int(np.argmin(difference))
        behind = int((difference < -BEHIND_TOLERANCE).sum())
        row = {
            "step": self.offset + step,
            "ssim_net": float(scores["ssim_net"].mean()),
            "ssim_linear": float(scores["ssim_linear"].mean()),
            "de2000_net": float(scores["de2000_net"].mean()),
            "de2000_linear": float(scores["de2000_linear"].mean()),
            "behind": behind,
            "worst_image": names[worst],
            "worst_difference": float(difference[worst]),
        }
        self._append(row)
        if behind:
            say(
                f"validation at step {self.offset + step}: the network is behind the DOE's linear filter on {behind} of "
                f"{len(names)} image(s), most on {names[worst]} (SSIM {difference[worst]:+.4f}); mean SSIM "
                f"{row['ssim_net']:.4f} vs {row['ssim_linear']:.4f}"
            )
        return row

    def _append(self, row: dict) -> None:
        new = not self.path.is_file()
        with self.path.open("a", newline="", encoding="utf-8") as handle:
            writer = csv.writer(handle)
            if new:
                writer.writerow(COLUMNS)
            writer.writerow([_format(row[c]) for c in COLUMNS])

    def _truncate_after(self, step: int) -> None:
        """Drop rows after ``step`` (a resumed run continues from its checkpoint)."""
        if not self.path.is_file():
            return
        with self.path.open(newline="", encoding="utf-8") as handle:
            rows = [r for r in csv.DictReader(handle) if int(r["step"]) <= step]
        buffer = io.StringIO()
        writer = csv.writer(buffer)
        writer.writerow(COLUMNS)
        writer.writerows([[r[c] for c in COLUMNS] for r in rows])
        write_text_atomic(self.path, buffer.getvalue())


def read_validation_log(path: str | Path) -> list[dict]:
    """Rows of ``validation_log.csv`` (numbers as floats, ``worst_image`` as text)."""
    with Path(path).open(newline="", encoding="utf-8") as handle:
        return [{k: (v if k == "worst_image" else float(v)) for k, v in row.items()} for row in csv.DictReader(handle)]


def _format(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, int):
        return str(value)
    return "" if math.isnan(value) else f"{value:.6g}"
