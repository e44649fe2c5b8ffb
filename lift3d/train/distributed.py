"""Data-parallel training with ``torch.distributed`` (launched by ``torchrun``).

``torchrun --nproc_per_node N -m lift3d train --data SCENE ...`` starts N processes. Each rank draws its own
rays and patches (its share of ``data.images_per_batch``), solves the per-image instance assignment for its
own images, and gradients are averaged by :class:`torch.nn.parallel.DistributedDataParallel`. Rank 0 writes
the run folder, checkpoints, logs and the progress bar. The backend is ``gloo`` on CPU and ``nccl`` on CUDA.

Checkpoints hold the plain (unwrapped) model, so they load in a single process and resume with any N.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class DistContext:
    """Where this process sits in the job."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def launched_by_torchrun() -> bool:
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def init_distributed(device_name: str) -> tuple[DistContext, str]:
    """Join the process group when started by torchrun (else a single-process context).

    Returns the context and the device name this rank should use (``cuda:<local_rank>`` with GPUs).
    """
    if not launched_by_torchrun():
        return DistContext(), device_name
    rank = int(os.environ["RANK"])
    world = int(os.environ["WORLD_SIZE"])
    local = int(os.environ.get("LOCAL_RANK", "0"))
    use_cuda = device_name.startswith("cuda") or (device_name == "auto" and torch.cuda.is_available())
    if use_cuda:
        torch.cuda.set_device(local)
        device_name = f"cuda:{local}"
    else:
        device_name = "cpu"
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if use_cuda else "gloo")
    return DistContext(rank, world, local), device_name


def broadcast_object(obj, ctx: DistContext):
    """Rank 0's ``obj`` on every rank (e.g. the run folder path)."""
    if not ctx.enabled:
        return obj
    box = [obj]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def barrier(ctx: DistContext) -> None:
    if ctx.enabled:
        dist.barrier()


def all_ranks_agree(flag: bool, ctx: DistContext) -> bool:
    """True when ``flag`` holds on every rank (e.g. "this step's loss is finite"): a step skipped on one
    rank must be skipped on all, or the gradient all-reduce would wait forever."""
    if not ctx.enabled:
        return flag
    t = torch.tensor([1.0 if flag else 0.0])
    dist.all_reduce(t, op=dist.ReduceOp.MIN)
    return bool(t.item() > 0.5)


def shutdown(ctx: DistContext) -> None:
    if ctx.enabled and dist.is_initialized():
        dist.destroy_process_group()
