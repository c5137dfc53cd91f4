"""Device settings (``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:1"``) turned into devices."""

from __future__ import annotations

import torch

__all__ = ["describe_device", "resolve_device", "synchronize"]


def resolve_device(name: str = "auto", local_rank: int = 0) -> torch.device:
    """Turn a device setting into a ``torch.device``.

    ``"auto"``: ``cuda:<local_rank>`` when CUDA is available, else ``cpu``. ``"cuda"`` picks
    ``cuda:<local_rank>``; an explicit ``"cuda:1"`` is kept. Asking for CUDA without it raises.
    """
    if not isinstance(name, str):
        raise TypeError(f"device must be a string like 'auto', 'cpu' or 'cuda', got {name!r}")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ValueError(f"device {name!r} is not a valid device ('auto', 'cpu', 'cuda', "
                         "'cuda:1', ...)") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device {name!r} asked for, but CUDA is not available here "
                             "(use device=auto or device=cpu)")
        index = local_rank if device.index is None else device.index
        if index >= torch.cuda.device_count():
            raise ValueError(f"device cuda:{index} asked for, but only "
                             f"{torch.cuda.device_count()} CUDA device(s) are visible")
        device = torch.device("cuda", index)
    return device


def synchronize() -> None:
    """Wait for the work queued on every CUDA device of this process (nothing on a CPU-only
    machine, or before CUDA was first used): call before reading a wall clock around GPU work,
    which runs asynchronously."""
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


def describe_device(device: torch.device | str) -> str:
    """``device`` and, for a GPU, its model name: what a measurement ran on (for logs and
    benchmark JSON)."""
    device = torch.device(device)
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return str(device)
