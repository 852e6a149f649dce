"""Data-parallel training across processes (``torchrun --nproc_per_node=N edofproj train ...``).

``torchrun`` starts N copies of the command with the environment variables ``RANK``,
``WORLD_SIZE``, ``LOCAL_RANK`` (and ``MASTER_ADDR``/``MASTER_PORT``). Each copy joins one
process group (``gloo`` on CPU, ``nccl`` on CUDA GPUs), holds a full replica of the DOE and
the network, draws its share of the global batch (:class:`~edofproj.training.sampling.BatchShard`)
and, wrapped in :class:`torch.nn.parallel.DistributedDataParallel`, averages the gradients
of all parameters (DOE and network alike) over the processes after each backward pass:

    g = (1/N) sum_r g_r,    g_r = gradient of rank r's mean loss over its B/N samples,

which equals the gradient of the mean loss over the global batch of B samples. Every rank
then takes the same optimizer step, so the replicas stay identical. Only rank 0 writes files.

A process started by ``torchrun`` joins the group even when it is alone
(``--nproc_per_node=1``): the collective path (NCCL on one GPU) then runs as it would on
several, and its result must equal that of a plain single-process run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from ..errors import EdofprojError


@dataclass(frozen=True)
class ProcessGroup:
    """This process's place in the run: ``rank`` of ``world_size``, and the device it computes on."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    joined: bool = False

    @property
    def distributed(self) -> bool:
        """Whether this process is in a process group (launched by ``torchrun``, even alone)."""
        return self.joined or self.world_size > 1

    @property
    def backend(self) -> str:
        """``nccl``, ``gloo`` or ``none`` (a plain single process)."""
        if not self.distributed:
            return "none"
        return "nccl" if self.device.type == "cuda" else "gloo"

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that writes logs, checkpoints and figures."""
        return self.rank == 0


def _env_int(name: str) -> int | None:
    value = os.environ.get(name)
    if value is None:
        return None
    try:
        return int(value)
    except ValueError:
        raise EdofprojError(f"environment variable {name}={value!r} must be an integer") from None


def choose_device(requested: str, local_rank: int = 0, option: str = "train.device") -> torch.device:
    """``auto`` (CUDA GPU ``local_rank`` when available, else CPU), ``cpu`` or ``cuda``; ``option``
    names the setting in the error raised when CUDA is asked for but absent."""
    if requested == "cpu":
        return torch.device("cpu")
    if requested == "cuda" and not torch.cuda.is_available():
        raise EdofprojError(f"{option}=cuda but no CUDA GPU is available to PyTorch (use cpu or auto)")
    if torch.cuda.is_available():
        return torch.device("cuda", local_rank % torch.cuda.device_count())
    return torch.device("cpu")


def setup_process_group(device: str = "auto") -> ProcessGroup:
    """Join the process group described by ``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` (if set).

    Without those variables (a plain ``edofproj train``) this is a single process, rank 0 that
    joins no group. With them (``torchrun``) the process joins the group, even as its only member.
    """
    launched = "WORLD_SIZE" in os.environ and "RANK" in os.environ
    world_size = _env_int("WORLD_SIZE") or 1
    rank = _env_int("RANK") or 0
    local_rank = _env_int("LOCAL_RANK") or 0
    chosen = choose_device(device, local_rank)
    if not launched:
        return ProcessGroup(0, 1, 0, chosen)
    if not dist.is_available():
        raise EdofprojError("this PyTorch build has no torch.distributed support")
    if not dist.is_initialized():
        backend = "nccl" if chosen.type == "cuda" else "gloo"
        if chosen.type == "cuda":
            torch.cuda.set_device(chosen)
        try:
            dist.init_process_group(backend=backend, rank=rank, world_size=world_size)
        except (RuntimeError, ValueError) as exc:
            first_line = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise EdofprojError(
                f"cannot join the {backend} process group as rank {rank} of {world_size} "
                f"(start data-parallel runs with torchrun): {first_line}"
            ) from None
    return ProcessGroup(rank, world_size, local_rank, chosen, joined=True)


def teardown_process_group(group: ProcessGroup) -> None:
    """Leave the process group (no-op for a single process)."""
    if group.distributed and dist.is_initialized():
        dist.destroy_process_group()


def average_across_processes(values: torch.Tensor, group: ProcessGroup) -> torch.Tensor:
    """The mean of ``values`` over all processes (a copy; unchanged for a single process)."""
    values = values.detach().clone()
    if group.distributed:
        values = values.to(group.device)  # nccl reduces GPU tensors only
        dist.all_reduce(values, op=dist.ReduceOp.SUM)
        values = (values / group.world_size).cpu()
    return values


def replica_max_difference(parameters, group: ProcessGroup) -> float:
    """``max_r max |theta_r - theta_0|`` over the processes' copies of ``parameters`` (0.0 when alone).

    Data-parallel replicas take identical steps, so this is exactly 0 unless they diverged.
    A collective call: every process must make it.
    """
    if not group.distributed:
        return 0.0
    tensors = [p.detach().reshape(-1).double() for p in parameters]
    flat = torch.cat(tensors) if tensors else torch.zeros(1, dtype=torch.float64, device=group.device)
    reference = flat.clone()
    dist.broadcast(reference, src=0)
    difference = (flat - reference).abs().max().reshape(1)
    dist.all_reduce(difference, op=dist.ReduceOp.MAX)
    return float(difference.item())


def barrier(group: ProcessGroup) -> None:
    if group.distributed:
        dist.barrier()
