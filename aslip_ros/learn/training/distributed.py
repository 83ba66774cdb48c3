"""``aslip train`` under ``torchrun --nproc_per_node N`` (#38): PyTorch's
DistributedDataParallel, gloo on the CPU and NCCL on GPUs, one machine or several.

``torchrun`` starts N copies of the same command with ``RANK``, ``WORLD_SIZE`` and
``LOCAL_RANK`` set; ``setup`` joins them into one process group. Then:

- every rank builds the same jobs and sees the same data; a CNN's global batch (``cfg``'s
  ``batch_size``) is shared out, each rank reading its own share of the windows
  (``share``), and DDP averages the gradients, so each step is the one-process step over
  the same windows (batch-norm statistics per rank, as DDP keeps them);
- every decision that depends on time (an epoch slice spent, the budget left, successive
  halving's rounds) reads rank 0's clock (``now``), and a choice that depends on measured
  latency is rank 0's (``agree``): every rank takes the same branches and trains the same
  candidates, and their collective calls pair up;
- rank 0 alone writes the checkpoint, the comparison and the resume states (``is_main``);
- the feature cache is built by rank 0 while the others wait (``rank0_first``).

Without ``torchrun`` every function is the one-process one; under ``torchrun`` with one
rank (one GPU) the group, DDP and NCCL are up all the same.
"""

from __future__ import annotations

import contextlib
import os
import time
from typing import Any, Iterator

import numpy as np
import torch


def _launched() -> bool:
    """Whether ``torchrun`` started this process (it sets these for every rank)."""
    return all(k in os.environ for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK",
                                         "MASTER_ADDR", "MASTER_PORT"))


def active() -> bool:
    """Whether this process is a rank of a process group (``torchrun``, even of one rank:
    one GPU's NCCL)."""
    import torch.distributed as dist
    return dist.is_available() and dist.is_initialized()


def setup(device: torch.device) -> None:
    """Join ``torchrun``'s process group where it started this process (gloo on the CPU,
    NCCL on CUDA; each rank on GPU ``LOCAL_RANK``); nothing otherwise."""
    import torch.distributed as dist
    if not _launched() or dist.is_initialized():
        return
    if device.type == "cuda":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    # On GPUs NCCL carries the gradients and gloo the small CPU tensors of ``now`` and
    # ``agree`` (NCCL has no CPU tensors: "No backend type associated with device type
    # cpu", seen on an H200).
    dist.init_process_group("cuda:nccl,cpu:gloo" if device.type == "cuda" else "gloo")


def teardown() -> None:
    import torch.distributed as dist
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def world() -> int:
    import torch.distributed as dist
    return dist.get_world_size() if active() else 1


def rank() -> int:
    import torch.distributed as dist
    return dist.get_rank() if active() else 0


def is_main() -> bool:
    """Rank 0 (or the only process): the one that writes files and logs."""
    return rank() == 0


def agree(obj: Any) -> Any:
    """Rank 0's ``obj`` on every rank (``obj`` itself in one process)."""
    if not active():
        return obj
    import torch.distributed as dist
    box = [obj]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def now() -> float:
    """``time.perf_counter()``, rank 0's on every rank: decisions taken on elapsed time
    are the same everywhere (every rank must call it at the same points)."""
    t = time.perf_counter()
    if not active():
        return t
    import torch.distributed as dist
    box = torch.tensor([t], dtype=torch.float64)
    dist.broadcast(box, src=0)
    return float(box.item())


@contextlib.contextmanager
def rank0_first() -> Iterator[None]:
    """Run the block on rank 0, then on the others (a cache rank 0 writes, they read)."""
    import torch.distributed as dist
    if active() and not is_main():
        dist.barrier()
    yield
    if active() and is_main():
        dist.barrier()


def share(batch: np.ndarray) -> np.ndarray:
    """This rank's share of one global batch of window indices."""
    return batch[rank()::world()] if active() else batch


def wrap(model: torch.nn.Module) -> torch.nn.Module:
    """``model`` for the training forward pass: DistributedDataParallel over the ranks
    (gradients averaged in ``backward``), or the model itself in one process."""
    if not active():
        return model
    from torch.nn.parallel import DistributedDataParallel
    dev = next(model.parameters()).device
    return DistributedDataParallel(model, device_ids=[dev.index] if dev.type == "cuda"
                                   else None)
