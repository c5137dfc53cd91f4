"""Several processes (GPUs or nodes) through ``torchrun`` and ``torch.distributed``.

Launch: ``torchrun --nproc_per_node 4 -m lisa_hand.cli.main train ...`` (or ``--nnodes``/
``--rdzv-endpoint`` for several nodes). torchrun sets ``RANK``, ``LOCAL_RANK``, ``WORLD_SIZE``,
``MASTER_ADDR`` and ``MASTER_PORT``; ``init_distributed`` reads them. Without them everything
runs as one process and no process group is created.

The data-parallel rule the engine relies on: every rank draws the *same global batch* from the
same generator (same seed, same draws), then keeps its own slice (``shard``). Gradients are
averaged over ranks (DistributedDataParallel does that), so a loss term that is a mean over the
batch must be written as ``global_mean(per_item_values_local, num_global)``, i.e.
``sum(local) * world_size / num_global``: the average over ranks of these is exactly the mean over
the global batch, and so is the averaged gradient, even when the batch does not divide evenly.
A term computed identically on every rank (a regulariser on the weights, a latent-code prior)
needs no scaling: its average over ranks is itself.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any, NoReturn

import torch
from torch import nn

from ..utils.device import resolve_device

__all__ = [
    "DistContext",
    "resolve_device",
    "init_distributed",
    "cleanup",
    "wrap_ddp",
    "unwrap",
    "shard_slice",
    "shard",
    "global_mean",
    "all_reduce_mean",
    "allreduce_gradients",
    "broadcast_module",
    "gather_objects",
    "barrier",
    "group_was_created",
    "end_process",
]

_GROUP_CREATED = False
"""Set when ``init_distributed`` has created a process group in this process."""


@dataclass(frozen=True)
class DistContext:
    """Where this process stands among the training processes."""

    rank: int = 0
    """Global rank of this process, 0 .. world_size - 1."""
    local_rank: int = 0
    """Rank on this node (selects the GPU)."""
    world_size: int = 1
    """Number of processes."""
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    """Device this process trains on."""
    backend: str | None = None
    """torch.distributed backend ('nccl', 'gloo'), None when running as one process."""
    owns_group: bool = False
    """True when ``init_distributed`` created the process group (``cleanup`` destroys it)."""

    @property
    def is_main(self) -> bool:
        """True on rank 0, the only rank that writes files and prints."""
        return self.rank == 0

    @property
    def is_distributed(self) -> bool:
        """True when there are several processes and a process group."""
        return self.world_size > 1 and self.backend is not None


def _env_int(name: str, default: int) -> int:
    value = os.environ.get(name)
    if value is None or value == "":
        return default
    try:
        return int(value)
    except ValueError:
        raise ValueError(f"environment variable {name} must be an integer, got {value!r}") \
            from None


def init_distributed(
    device: str = "auto", backend: str | None = None, timeout_s: float = 1800.0
) -> DistContext:
    """Join the process group described by torchrun's environment, or run as one process.

    Reads ``RANK``, ``LOCAL_RANK``, ``WORLD_SIZE`` (and ``MASTER_ADDR``/``MASTER_PORT`` through
    ``init_method="env://"``). With ``WORLD_SIZE`` unset or 1, returns a one-process context. The
    backend defaults to NCCL on CUDA and gloo on CPU. If a process group already exists (the
    caller initialised it), it is used as is and ``owns_group`` is False.
    """
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        rank, world_size = dist.get_rank(), dist.get_world_size()
        local_rank = _env_int("LOCAL_RANK", rank)
        dev = resolve_device(device, local_rank)
        return DistContext(rank, local_rank, world_size, dev, dist.get_backend(), False)
    world_size = _env_int("WORLD_SIZE", 1)
    rank = _env_int("RANK", 0)
    local_rank = _env_int("LOCAL_RANK", 0)
    if world_size < 1 or not 0 <= rank < world_size:
        raise ValueError(f"inconsistent torchrun environment: RANK={rank}, "
                         f"WORLD_SIZE={world_size}")
    dev = resolve_device(device, local_rank)
    if world_size == 1:
        return DistContext(0, local_rank, 1, dev, None, False)
    if not dist.is_available():
        raise RuntimeError("WORLD_SIZE > 1 but this torch build has no torch.distributed")
    for name in ("MASTER_ADDR", "MASTER_PORT"):
        if not os.environ.get(name):
            raise ValueError(f"WORLD_SIZE={world_size} but {name} is not set; launch with "
                             "torchrun (it sets RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT)")
    if backend is None:
        backend = "nccl" if dev.type == "cuda" else "gloo"
    if backend == "nccl" and dev.type != "cuda":
        raise ValueError(f"backend 'nccl' needs CUDA devices, but the device is {dev}")
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    kwargs = {}
    if backend == "nccl":
        kwargs["device_id"] = dev  # binds the communicator to the device (no guessing)
    try:
        dist.init_process_group(backend=backend, init_method="env://", rank=rank,
                                world_size=world_size, timeout=timedelta(seconds=timeout_s),
                                **kwargs)
    except TypeError:  # older torch without device_id
        dist.init_process_group(backend=backend, init_method="env://", rank=rank,
                                world_size=world_size, timeout=timedelta(seconds=timeout_s))
    global _GROUP_CREATED
    _GROUP_CREATED = True
    return DistContext(rank, local_rank, world_size, dev, backend, True)


def cleanup(ctx: DistContext) -> None:
    """Destroy the process group if ``init_distributed`` created it."""
    import torch.distributed as dist

    if ctx.owns_group and dist.is_available() and dist.is_initialized():
        # Every rank must be done with its collectives before any tears the group down: a gloo
        # peer that closes its sockets early makes the other rank abort at exit.
        barrier(ctx)
        dist.destroy_process_group()


def group_was_created() -> bool:
    """True when ``init_distributed`` created a process group in this process (its end should
    then go through ``end_process``)."""
    return _GROUP_CREATED


def end_process(status: int = 0) -> NoReturn:
    """End a torchrun worker process now, without Python's interpreter teardown.

    Gloo's worker threads outlive ``destroy_process_group`` (torch keeps references to the
    group), and one of them may drop its last reference to a finished collective's tensor while
    the interpreter tears down; that needs the GIL, which a finalizing interpreter no longer
    gives, so the process aborts ("terminate called without an active exception") after its work
    is done, and torchrun reports the run as failed (in about 1 run in 40 on 2 cores). Call it
    after ``cleanup``: files are written and closed by then (checkpoints atomically); stdout and
    stderr are flushed here.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or gone: nothing left to flush
            pass
    os._exit(status)


def barrier(ctx: DistContext) -> None:
    """Wait for every rank (no-op for one process)."""
    if ctx.is_distributed:
        import torch.distributed as dist

        if ctx.backend == "nccl":
            dist.barrier(device_ids=[ctx.device.index])
        else:
            dist.barrier()


def wrap_ddp(model: nn.Module, ctx: DistContext, **ddp_kwargs: Any) -> nn.Module:
    """Wrap ``model`` (already on ``ctx.device``) in DistributedDataParallel; one process: as is.

    DDP broadcasts rank 0's parameters and buffers at construction, so every rank starts from
    the same weights. Only calls through the wrapper's ``forward`` synchronise gradients.
    """
    if not ctx.is_distributed:
        return model
    from torch.nn.parallel import DistributedDataParallel

    device_ids = [ctx.device.index] if ctx.device.type == "cuda" else None
    return DistributedDataParallel(model, device_ids=device_ids, **ddp_kwargs)


def unwrap(model: nn.Module) -> nn.Module:
    """The module inside a DistributedDataParallel or ``torch.compile`` wrapper; else ``model``."""
    from torch.nn.parallel import DistributedDataParallel

    while True:
        if isinstance(model, DistributedDataParallel):
            model = model.module
        elif type(model).__name__ == "OptimizedModule" and hasattr(model, "_orig_mod"):
            model = model._orig_mod
        else:
            return model


def shard_slice(num_items: int, ctx: DistContext) -> slice:
    """This rank's contiguous slice of a global batch of ``num_items`` items.

    Rank r gets items ``[r * num_items // W, (r + 1) * num_items // W)``: sizes differ by at
    most one and the slices cover the batch exactly once.
    """
    if not isinstance(num_items, int) or num_items < 0:
        raise ValueError(f"num_items must be a non-negative int, got {num_items!r}")
    if num_items < ctx.world_size:
        raise ValueError(f"a global batch of {num_items} items cannot be split among "
                         f"{ctx.world_size} ranks (each rank needs at least one)")
    start = ctx.rank * num_items // ctx.world_size
    stop = (ctx.rank + 1) * num_items // ctx.world_size
    return slice(start, stop)


def shard(batch: Any, ctx: DistContext, dim: int = 0) -> Any:
    """This rank's slice of a global batch along ``dim``.

    ``batch`` is a tensor ``[N, ...]`` or a dict/list/tuple of tensors that all share the size
    ``N`` along ``dim``; non-tensor leaves are returned as is. One process: ``batch`` unchanged.
    """
    if ctx.world_size == 1:
        return batch
    sizes = {t.shape[dim] for t in _tensors(batch)}
    if len(sizes) != 1:
        raise ValueError(f"shard: the tensors of the batch disagree on their size along dim "
                         f"{dim}: {sorted(sizes)}")
    part = shard_slice(sizes.pop(), ctx)
    return _map_tensors(batch, lambda t: t.narrow(dim, part.start, part.stop - part.start))


def _tensors(tree: Any) -> list[torch.Tensor]:
    if isinstance(tree, torch.Tensor):
        return [tree]
    if isinstance(tree, Mapping):
        return [t for v in tree.values() for t in _tensors(v)]
    if isinstance(tree, (list, tuple)):
        return [t for v in tree for t in _tensors(v)]
    return []


def _map_tensors(tree: Any, fn: Any) -> Any:
    if isinstance(tree, torch.Tensor):
        return fn(tree)
    if isinstance(tree, Mapping):
        return type(tree)((k, _map_tensors(v, fn)) for k, v in tree.items())
    if isinstance(tree, tuple) and hasattr(tree, "_fields"):  # namedtuple
        return type(tree)(*(_map_tensors(v, fn) for v in tree))
    if isinstance(tree, (list, tuple)):
        return type(tree)(_map_tensors(v, fn) for v in tree)
    return tree


def global_mean(values_local: torch.Tensor, num_global: int, ctx: DistContext) -> torch.Tensor:
    """This rank's share of the mean over the global batch: ``sum(values_local) * W / num_global``.

    values_local: [n_local, ...] per-item values of this rank's slice (summed over all dims).
    num_global: number of items (same unit as the summed elements) in the global batch.
    Averaged over ranks (as DDP averages gradients) this is the global mean exactly. With one
    process it is ``values.sum() / num_global``, i.e. the plain mean when ``num_global`` is the
    element count.
    """
    if num_global <= 0:
        raise ValueError(f"num_global must be positive, got {num_global}")
    return values_local.sum() * (ctx.world_size / num_global)


def all_reduce_mean(tensor: torch.Tensor, ctx: DistContext) -> torch.Tensor:
    """Average ``tensor`` over ranks (a new tensor; one process: a detached copy)."""
    out = tensor.detach().clone()
    if ctx.is_distributed:
        import torch.distributed as dist

        dist.all_reduce(out, op=dist.ReduceOp.SUM)
        out /= ctx.world_size
    return out


def allreduce_gradients(parameters: Iterable[nn.Parameter], ctx: DistContext) -> None:
    """Average the gradients of ``parameters`` over ranks in place (without DDP).

    Works whatever way the step function called the model. A parameter whose gradient is None
    on some ranks but not others gets zeros there (so the average matches one process on the
    global batch); a parameter without a gradient on every rank keeps None.
    """
    if not ctx.is_distributed:
        return
    import torch.distributed as dist

    params = [p for p in parameters if p.requires_grad]
    if not params:
        return
    device = params[0].device
    has_grad = torch.tensor([p.grad is not None for p in params], dtype=torch.float32,
                            device=device)
    dist.all_reduce(has_grad, op=dist.ReduceOp.SUM)
    used = [p for p, count in zip(params, has_grad.tolist(), strict=True) if count > 0]
    # One flat buffer per dtype: a single collective per dtype instead of one per parameter.
    by_dtype: dict[torch.dtype, list[nn.Parameter]] = {}
    for p in used:
        by_dtype.setdefault(p.dtype, []).append(p)
    for group in by_dtype.values():
        flat = torch.cat([
            (p.grad if p.grad is not None else torch.zeros_like(p)).reshape(-1) for p in group
        ])
        dist.all_reduce(flat, op=dist.ReduceOp.SUM)
        flat /= ctx.world_size
        offset = 0
        for p in group:
            numel = p.numel()
            p.grad = flat[offset:offset + numel].view_as(p)
            offset += numel


def broadcast_module(model: nn.Module, ctx: DistContext, src: int = 0) -> None:
    """Copy rank ``src``'s parameters and buffers onto every rank (in place)."""
    if not ctx.is_distributed:
        return
    import torch.distributed as dist

    with torch.no_grad():
        for tensor in list(model.parameters()) + list(model.buffers()):
            dist.broadcast(tensor.data, src=src)


def gather_objects(obj: Any, ctx: DistContext) -> list[Any]:
    """Every rank's ``obj`` (picklable), in rank order, on every rank; one process: ``[obj]``."""
    if not ctx.is_distributed:
        return [obj]
    import torch.distributed as dist

    out: list[Any] = [None] * ctx.world_size
    dist.all_gather_object(out, obj)
    return out
