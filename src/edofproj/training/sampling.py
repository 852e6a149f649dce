"""Random draws of a training step, defined per *global* batch index.

Every random quantity of sample ``i`` (0 <= i < batch_size) at step ``t`` comes from its own
generator, seeded from ``(seed, t, i, stream)``:

    stream 0: the training image crop,    stream 1: the screen depth z,    stream 2: camera noise,
    stream 3: the surface (``net.surface_input``: texture and ambient).

Nothing depends on how the batch is split across processes or on what ran before, so

* a data-parallel run on ``N`` processes, where rank ``r`` draws the indices
  ``[r B/N, (r+1) B/N)``, sees exactly the union of a single-process run's batch;
* resuming at step ``t`` draws the same samples as an uninterrupted run.

Depths (paper Sec. 4.1, "arbitrary depths ranging from 300 mm to 800 mm"):

* ``uniform``:    z_i = z_min + u_i (z_max - z_min),                u_i ~ U(0, 1);
* ``stratified``: z_i = z_min + (i + u_i) / B (z_max - z_min):  one draw in each of B
  equal sub-ranges, so every batch covers the whole range (lower-variance gradients for
  small batches; still uniform marginally).

With ``spacing="defocus"`` the same ``u`` is spread uniformly in inverse depth (defocus,
diopters) instead: ``1/z = 1/z_min + u (1/z_max - 1/z_min)``. The blur-disk diameter grows
like ``|1/z - 1/v|``, so this spends equal effort per unit of defocus.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import EdofprojError
from ..scenes.random_screens import random_depth_map

IMAGE_STREAM = 0
DEPTH_STREAM = 1
NOISE_STREAM = 2
SURFACE_STREAM = 3

DEPTH_SAMPLING = ("uniform", "stratified")


def sample_generator(seed: int, step: int, index: int, stream: int) -> torch.Generator:
    """A torch generator for sample ``index`` of step ``step`` and random ``stream``.

    The seed is mixed by :class:`numpy.random.SeedSequence` (hash-quality, order-sensitive),
    so neighbouring (step, index) pairs give unrelated streams.
    """
    state = np.random.SeedSequence([int(seed), int(step), int(index), int(stream)]).generate_state(2, np.uint32)
    generator = torch.Generator()
    generator.manual_seed(int(state[0]) << 32 | int(state[1]))
    return generator


@dataclass(frozen=True)
class BatchShard:
    """The global batch indices ``[start, stop)`` that one process draws."""

    start: int
    stop: int
    global_size: int

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def indices(self) -> range:
        return range(self.start, self.stop)

    @classmethod
    def for_rank(cls, global_size: int, rank: int, world_size: int) -> "BatchShard":
        """Rank ``rank``'s equal share of a global batch of ``global_size`` samples."""
        if world_size < 1 or not (0 <= rank < world_size):
            raise EdofprojError(f"rank {rank} is not in a world of {world_size} processes")
        if global_size % world_size:
            raise EdofprojError(
                f"train.batch_size={global_size} must be divisible by the number of processes ({world_size})"
            )
        per_rank = global_size // world_size
        return cls(rank * per_rank, (rank + 1) * per_rank, global_size)


def sample_depths_m(
    seed: int,
    step: int,
    shard: BatchShard,
    depth_min_m: float,
    depth_max_m: float,
    mode: str = "uniform",
    spacing: str = "depth",
) -> np.ndarray:
    """Screen depths (m) of the shard's samples at ``step`` (see the module docstring)."""
    if mode not in DEPTH_SAMPLING:
        raise EdofprojError(f"depth sampling '{mode}' is not one of {', '.join(DEPTH_SAMPLING)}")
    if spacing not in ("depth", "defocus"):
        raise EdofprojError(f"depth spacing '{spacing}' is not one of depth, defocus")
    depths = []
    for i in shard.indices:
        u = float(torch.rand((), generator=sample_generator(seed, step, i, DEPTH_STREAM), dtype=torch.float64))
        if mode == "stratified":
            u = (i + u) / shard.global_size
        if spacing == "defocus":
            depths.append(1.0 / (1.0 / depth_min_m + u * (1.0 / depth_max_m - 1.0 / depth_min_m)))
        else:
            depths.append(depth_min_m + u * (depth_max_m - depth_min_m))
    return np.asarray(depths, dtype=np.float64)


def sample_images(source, seed: int, step: int, shard: BatchShard, crop: int) -> torch.Tensor:
    """Training crops ``(shard.size, 3, crop, crop)``: one ``source.sample(1, crop, g_i)`` per index."""
    crops = [source.sample(1, crop, sample_generator(seed, step, i, IMAGE_STREAM)) for i in shard.indices]
    return torch.cat(crops, dim=0)


def sample_noise(seed: int, step: int, shard: BatchShard, shape: tuple[int, ...]) -> torch.Tensor:
    """Standard normal noise ``(shard.size, *shape)`` for the camera model."""
    return torch.stack(
        [torch.randn(shape, generator=sample_generator(seed, step, i, NOISE_STREAM)) for i in shard.indices]
    )


def sample_depth_maps(
    seed: int, step: int, shard: BatchShard, size_px: int, depth_min_m: float, depth_max_m: float
) -> np.ndarray:
    """Random depth-varying screens ``(shard.size, size, size)`` in metres (``train.screens: varying``),
    one per sample from its depth stream (:func:`edofproj.scenes.random_screens.random_depth_map`)."""
    maps = [
        random_depth_map(sample_generator(seed, step, i, DEPTH_STREAM), size_px, size_px, depth_min_m, depth_max_m)[0]
        for i in shard.indices
    ]
    return np.stack(maps)


def sample_surfaces(surfaces, seed: int, step: int, shard: BatchShard, crop: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Training surfaces ``(reflectance, ambient)``, each ``(shard.size, 3, crop, crop)``: one
    ``surfaces.draw(crop, g_i)`` per index (:class:`~edofproj.data.textures.TrainingSurfaces`)."""
    draws = [surfaces.draw(crop, sample_generator(seed, step, i, SURFACE_STREAM)) for i in shard.indices]
    return torch.stack([rho for rho, _ in draws]), torch.stack([ambient for _, ambient in draws])
