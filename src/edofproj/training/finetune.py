"""Fine-tuning the compensation network on measured PSFs (paper Sec. 5.3: 20 iterations, 300–900 mm).

The DOE is fixed (it has been fabricated); only the network learns. The PSFs come from
``.npz`` files in the ``edofproj psf`` format (e.g. written by ``edofproj procams estimate-psf``,
one file per measured depth or several depths per file). Between measured depths the PSF is
interpolated linearly in inverse depth, in which the defocus blur is linear
(b(z) = D T W |1/z - 1/v| pixels):

    PSF(z) = (1 - t) PSF(z_i) + t PSF(z_{i+1}),   t = (1/z - 1/z_i) / (1/z_{i+1} - 1/z_i).

**Per-patch PSFs** (``edofproj procams estimate-psf --patch-psfs``: one PSF per image patch,
``psf (P, 3, K, K)``): with ``per_patch=True`` the table holds ``(n_depths, P, 3, K, K)`` and
each training sample draws one patch -- a field point -- uniformly, so the network learns the
PSFs across the image instead of their mean (a training crop is small against the field, so
the PSF is taken as constant within it).

**PSF maps** (``edofproj procams psf-map``: the blur a real projector shows across its image, a
Gaussian per projector point): with ``psf_map`` the table holds the kernels of the map's nodes
(:func:`edofproj.procams.measured_blur.measured_blur`, nodes ``MAP_NODE_SPACING_PX`` apart; each
colour its own map where the file has one) as the patches of one nominal depth (the middle of the
run's range: the map is one surface, not a depth), and each sample draws a node, so the network
learns every blur the map holds; ``edofproj compensate --psf-map MAP --method net`` then gives it
the map's field-varying projection of the target as its capture.

Each step draws depths uniformly in the measured range and training crops, renders
``I* = project(I, PSF(z))``, and minimizes the run's loss on ``project(clamp(net(I, I*)), PSF(z))``,
exactly as in joint training (:mod:`.end_to_end`). The result is a new run directory (the
original run is never modified) that ``edofproj evaluate``/``compensate``/``export`` accept.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from ..data import build_training_source
from ..errors import EdofprojError
from ..fileio import read_arrays, write_text_atomic
from ..locking import directory_lock
from ..optics.psf_bank import PSFBank
from ..optics.psf_checks import validate_psf
from ..procams.measured_blur import map_file_blur
from ..runs import CHECKPOINT_DIR, DOE_NAME, check_new_run_dir, load_run, write_run_config
from ..runs.checkpoint import save_checkpoint
from .end_to_end import EndToEndProjector
from .losses import build_loss
from .sampling import BatchShard, sample_depths_m, sample_images, sample_noise
from .trainer import loss_terms, seed_everything

MAP_NODE_SPACING_PX = 32
"""Spacing (projector px) of the PSF map's nodes whose kernels a map fine-tuning draws from."""


class MeasuredPSFTable(nn.Module):
    """PSFs measured at arbitrary depths; ``table(depths_m) -> (B, C, K, K)`` interpolated in 1/z.

    ``psf``: ``(n_depths, C, K, K)``, or ``(n_depths, P, C, K, K)`` per patch (field point), in
    which case each sample draws a patch uniformly (``seed``)."""

    psf: torch.Tensor  # buffer

    def __init__(self, psf: torch.Tensor, depths_m, seed: int = 0) -> None:
        super().__init__()
        self.generator = torch.Generator().manual_seed(int(seed))
        depths_m = np.asarray(depths_m, dtype=np.float64)
        order = np.argsort(-depths_m)  # increasing inverse depth
        self.register_buffer("psf", psf[torch.as_tensor(order.copy())].float().clone())
        self.depths_m = depths_m[order]
        self.inverse = torch.as_tensor(1.0 / self.depths_m)

    @classmethod
    def from_files(cls, paths) -> "MeasuredPSFTable":
        """Load and merge PSF files; they must share the window and hold RGB (or grey) PSFs."""
        psfs, depths = [], []
        for path in paths:
            bank = PSFBank.load(path)
            if bank.psf.shape[1] not in (1, 3):
                raise EdofprojError(f"PSF file '{path}' has {bank.psf.shape[1]} channels; expected 3 (RGB) or 1")
            psfs.append(bank.psf.expand(-1, 3, -1, -1) if bank.psf.shape[1] == 1 else bank.psf)
            depths.extend(bank.depths_m.tolist())
        windows = {p.shape[-1] for p in psfs}
        if len(windows) != 1:
            raise EdofprojError(
                f"the measured PSF files have different windows {sorted(windows)}: re-estimate "
                "them with the same --window"
            )
        depths_m = np.asarray(depths)
        if len(np.unique(np.round(depths_m, 6))) != len(depths_m):
            raise EdofprojError(f"the measured PSF files repeat a depth: {np.round(depths_m * 1e3, 1).tolist()} mm")
        return cls(torch.cat(psfs), depths_m)

    @classmethod
    def from_patch_files(cls, paths, seed: int = 0) -> "MeasuredPSFTable":
        """Load per-patch PSF files (``estimate-psf --patch-psfs``: ``psf (P, 3, K, K)`` and
        ``depths_m (1,)``); they must share the window and the patch count."""
        psfs, depths = [], []
        for path in paths:
            data = read_arrays(path, what="per-patch PSF file")
            if "psf" not in data or "depths_m" not in data:
                raise EdofprojError(f"per-patch PSF file '{path}' must hold 'psf' and 'depths_m'")
            psf, depth = data["psf"], data["depths_m"]
            if psf.dtype.kind not in "fiu" or depth.dtype.kind not in "fiu":
                raise EdofprojError(f"per-patch PSF file '{path}' holds non-numeric arrays")
            if psf.ndim != 4 or psf.shape[1] != 3 or psf.shape[-1] != psf.shape[-2] or np.size(depth) != 1:
                raise EdofprojError(
                    f"per-patch PSF file '{path}' must hold psf (P, 3, K, K) and one depth, got {psf.shape}"
                )
            validate_psf(psf, np.full(len(psf), float(np.ravel(depth)[0])), f"per-patch PSF file '{path}'")
            psfs.append(torch.from_numpy(psf.astype(np.float32)))
            depths.append(float(np.ravel(depth)[0]))
        if len({p.shape for p in psfs}) != 1:
            raise EdofprojError(
                f"the per-patch PSF files differ in patches or window {sorted({tuple(p.shape) for p in psfs})}: "
                "estimate them with the same --patch and --window"
            )
        if len(np.unique(np.round(depths, 6))) != len(depths):
            raise EdofprojError(
                f"the per-patch PSF files repeat a depth: {np.round(np.array(depths) * 1e3, 1).tolist()} mm"
            )
        return cls(torch.stack(psfs), np.asarray(depths), seed)

    @classmethod
    def from_psf_map(cls, path, depth_m: float, seed: int = 0) -> "MeasuredPSFTable":
        """The node kernels of a PSF map (``edofproj procams psf-map``, Gaussian or kernel map; each colour
        its own map where the file has one) as per-patch PSFs at one nominal depth ``depth_m``: each sample draws a node
        (module docstring, **PSF maps**)."""
        op = map_file_blur(path, node_spacing_px=MAP_NODE_SPACING_PX, rank_tolerance=0.0)
        kernels = op.kernels.reshape(-1, *op.kernels.shape[2:]).to(torch.float32)  # (P, C|1, K, K)
        return cls(kernels.expand(-1, 3, -1, -1)[None].contiguous(), np.array([float(depth_m)]), seed)

    @property
    def depth_range_m(self) -> tuple[float, float]:
        return float(self.depths_m.min()), float(self.depths_m.max())

    def forward(self, depths_m) -> torch.Tensor:
        inverse = 1.0 / torch.as_tensor(np.asarray(depths_m, dtype=np.float64))
        lo, hi = float(self.inverse[0]), float(self.inverse[-1])
        if torch.any(inverse < lo - 1e-9) or torch.any(inverse > hi + 1e-9):
            raise EdofprojError(
                f"depths outside the measured {self.depths_m.min() * 1e3:.0f}-{self.depths_m.max() * 1e3:.0f} mm"
            )
        n = len(self.depths_m)
        table = self.psf
        if table.ndim == 5:  # per patch: one field point per sample
            patch = torch.randint(table.shape[1], (len(inverse),), generator=self.generator)
            table = table[:, patch]  # (n_depths, B, C, K, K)
            pick = lambda index: table[index, torch.arange(len(inverse))]  # noqa: E731
        else:
            pick = lambda index: table[index]  # noqa: E731
        if n == 1:
            return pick(torch.zeros(len(inverse), dtype=torch.long))
        upper = torch.searchsorted(self.inverse, inverse.clamp(lo, hi)).clamp(1, n - 1)
        lower = upper - 1
        t = ((inverse - self.inverse[lower]) / (self.inverse[upper] - self.inverse[lower])).clamp(0, 1)
        t = t.to(self.psf.dtype)[:, None, None, None]
        return (1 - t) * pick(lower) + t * pick(upper)


@dataclass
class FinetuneResult:
    run_dir: Path
    steps: int
    depth_range_m: tuple[float, float]
    first_loss: float
    last_loss: float


def finetune(
    run_dir,
    psf_files,
    out_dir,
    steps: int = 20,
    lr: float | None = None,
    batch_size: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    per_patch: bool = False,
    psf_map=None,
) -> FinetuneResult:
    """Fine-tune the network of ``run_dir`` on measured PSFs; write a new run to ``out_dir``.

    ``per_patch``: ``psf_files`` are per-patch files (``estimate-psf --patch-psfs``) and each
    sample draws a patch (module docstring). ``psf_map``: a PSF map file instead of ``psf_files``
    (each sample draws a node of the map; module docstring).

    ``lr`` defaults to the run's ``train.lr_net`` times its final decay fraction (where its
    schedule ended); ``batch_size`` and ``seed`` default to the run's.
    """
    if steps < 1:
        raise EdofprojError(f"--steps {steps} must be >= 1")
    if lr is not None and not (math.isfinite(lr) and lr > 0):
        raise EdofprojError(f"--lr {lr} must be a positive, finite learning rate")
    if batch_size is not None and batch_size < 1:
        raise EdofprojError(f"--batch-size {batch_size} must be >= 1")
    if psf_map is not None and psf_files:
        raise EdofprojError("give measured PSF files or a PSF map, not both")
    if not psf_files and psf_map is None:
        raise EdofprojError("give at least one measured PSF file with --psfs (or a PSF map with --psf-map)")
    out_dir = Path(out_dir)
    if out_dir.resolve() == Path(run_dir).resolve():
        raise EdofprojError("--out must differ from the run directory: fine-tuning never overwrites the run")
    with directory_lock(out_dir, "edofproj finetune", "--out"):
        check_new_run_dir(out_dir, hint="fine-tuning writes a new run directory: choose another --out")
        return _finetune(run_dir, psf_files, out_dir, steps, lr, batch_size, seed, progress, per_patch, psf_map)


def _finetune(
    run_dir, psf_files, out_dir: Path, steps, lr, batch_size, seed, progress, per_patch, psf_map=None
) -> FinetuneResult:
    trained = load_run(run_dir)
    table_seed = trained.cfg.train.seed if seed is None else seed
    if psf_map is not None:
        nominal_m = 0.5e-3 * (trained.cfg.psf.depth_min_mm + trained.cfg.psf.depth_max_mm)
        table = MeasuredPSFTable.from_psf_map(psf_map, nominal_m, table_seed)
    elif per_patch:
        table = MeasuredPSFTable.from_patch_files(psf_files, table_seed)
    else:
        table = MeasuredPSFTable.from_files(psf_files)
    cfg = trained.cfg
    z_min, z_max = table.depth_range_m
    depth_range_mm = (cfg.psf.depth_min_mm, cfg.psf.depth_max_mm) if psf_map is not None else (z_min * 1e3, z_max * 1e3)
    train_cfg = dataclasses.replace(
        cfg.train,
        batch_size=cfg.train.batch_size if batch_size is None else batch_size,
        seed=cfg.train.seed if seed is None else seed,
        steps=steps,
        train_doe=False,
    )
    cfg = dataclasses.replace(
        cfg,
        train=train_cfg,
        name=f"{cfg.name}-finetuned",
        psf=dataclasses.replace(cfg.psf, depth_min_mm=depth_range_mm[0], depth_max_mm=depth_range_mm[1]),
    )
    cfg.check_memory()  # a training step of --batch-size crops, before it is drawn
    seed_everything(cfg.train.seed)

    net = trained.net
    net.train()
    for p in net.parameters():
        p.requires_grad_(True)
    model = EndToEndProjector(table, net, cfg.train.noise_sigma, cfg.train.quantize_capture)
    learning_rate = lr if lr is not None else cfg.train.lr_net * cfg.train.lr_final_fraction
    optimizer = torch.optim.Adam(net.parameters(), lr=learning_rate)
    loss_fn = build_loss(cfg.loss)
    source = build_training_source(cfg.data, cfg.train.seed)
    shard = BatchShard.for_rank(cfg.train.batch_size, 0, 1)

    rows = []
    bar = None
    if progress:
        bar = tqdm(total=steps, unit="step", dynamic_ncols=True, desc="finetune")
    clock = time.perf_counter()
    for step in range(1, steps + 1):
        depths = sample_depths_m(cfg.train.seed, step, shard, z_min, z_max, "uniform")
        images = sample_images(source, cfg.train.seed, step, shard, cfg.data.crop)
        noise = (
            sample_noise(cfg.train.seed, step, shard, tuple(images.shape[1:])) if cfg.train.noise_sigma > 0 else None
        )
        out = model(images, depths, noise)
        loss, mse, perceptual = loss_terms(loss_fn, cfg, out.projected, images)
        if not torch.isfinite(loss):
            raise EdofprojError(f"fine-tuning stopped: the loss became {float(loss)} at step {step}; nothing written")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.train.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.train.grad_clip)
        optimizer.step()
        rows.append((step, float(loss), float(mse), float(perceptual), learning_rate, time.perf_counter() - clock))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{float(loss):.4g}")
    if bar is not None:
        bar.close()

    out_dir.mkdir(parents=True, exist_ok=True)
    write_run_config(out_dir, cfg)
    source_doe = Path(run_dir) / DOE_NAME
    if source_doe.is_file():
        shutil.copyfile(source_doe, out_dir / DOE_NAME)
    net.eval()
    save_checkpoint(
        out_dir / CHECKPOINT_DIR,
        {
            "step": steps,
            "net": net.state_dict(),
            "doe": {},
            "finetuned_from": str(run_dir),
            "measured_psfs": [str(p) for p in psf_files or []],
            "per_patch": bool(per_patch or psf_map is not None),
            "psf_map": None if psf_map is None else str(psf_map),
            "measured_depths_m": table.depths_m.tolist(),
        },
    )
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(["step", "loss", "mse", "perceptual", "lr", "seconds"])
    writer.writerows(rows)
    write_text_atomic(out_dir / "train_log.csv", text.getvalue())
    return FinetuneResult(out_dir, steps, (z_min, z_max), rows[0][1], rows[-1][1])
