"""The training loop's settings (:class:`TrainerConfig`) and what they build: the optimizer
(:func:`build_optimizer`, the one place that makes Adam, AdamW or SGD for every run) and the
learning-rate schedule (:func:`lr_factor`, :func:`build_scheduler`).

Also the two field checks that the run configs (``PriorConfig``, ``ImageTrainConfig``) share
with :class:`TrainerConfig` (:func:`check_positive_int`, :func:`check_non_negative`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import nn

__all__ = [
    "LR_SCHEDULES",
    "OPTIMIZERS",
    "TrainerConfig",
    "lr_factor",
    "build_optimizer",
    "build_scheduler",
    "check_positive_int",
    "check_non_negative",
]

LR_SCHEDULES = ("constant", "cosine", "exponential")
OPTIMIZERS = ("adam", "adamw", "sgd")


def check_positive_int(config: Any, name: str, allow_zero: bool = False) -> None:
    """Raise ``ValueError`` unless ``config.<name>`` is an int (bools excluded) >= 1 (>= 0 with
    ``allow_zero``)."""
    value = getattr(config, name)
    low = 0 if allow_zero else 1
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        kind = "a non-negative" if allow_zero else "a positive"
        raise ValueError(f"{name} must be {kind} int, got {value!r}")


def check_non_negative(config: Any, name: str) -> None:
    """Raise ``ValueError`` unless ``config.<name>`` is a finite number >= 0 (bools excluded)."""
    value = getattr(config, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class TrainerConfig:
    """Settings of the training loop (the model, data and losses have their own configs)."""

    steps: int = 10_000
    """Total number of optimizer steps of the run (a resumed run continues up to it)."""
    lr: float = 5e-4
    """Peak learning rate (of every parameter group the default optimizer builds)."""
    lr_schedule: Literal["constant", "cosine", "exponential"] = "constant"
    """Learning-rate decay over the run: 'constant', 'cosine' (to lr * lr_final_factor at the
    last step) or 'exponential' (geometric, to lr * lr_final_factor at the last step)."""
    lr_final_factor: float = 0.1
    """Learning rate at the end of the run, as a fraction of ``lr`` (cosine, exponential)."""
    warmup_steps: int = 0
    """Linear warm-up from lr / warmup_steps to lr over the first steps (0: none)."""
    optimizer: Literal["adam", "adamw", "sgd"] = "adam"
    """Optimizer built when the caller gives no ``optimizer_fn``."""
    betas: tuple[float, float] = (0.9, 0.999)
    """Adam(W) moment decay rates (SGD: betas[0] is the momentum)."""
    weight_decay: float = 0.0
    """Weight decay of the default optimizer (decoupled for 'adamw')."""
    grad_clip: float = 0.0
    """Clip the global gradient norm to this value (0: no clipping)."""
    checkpoint_every: int = 1000
    """Write ``last.pt`` every this many steps (and always at the end); 0: only at the end."""
    keep_every: int = 0
    """Also keep a copy ``step_XXXXXXXX.pt`` every this many steps (0: keep only last.pt)."""
    log_every: int = 1
    """Append the losses to ``log.jsonl`` every this many steps (and at the last step)."""
    print_every: int = 100
    """When the progress bar is on but stderr is not a terminal, print a line of losses every
    this many steps instead (0: never)."""
    seed: int = 0
    """Seed of the data generator and of the global RNGs at the start of a fresh run."""
    device: str = "auto"
    """'auto' (CUDA when available, else CPU), 'cpu', 'cuda' or 'cuda:N'. Under torchrun each
    rank uses cuda:LOCAL_RANK."""
    progress: bool = True
    """Show a progress bar with the losses (rank 0, terminals only)."""
    grad_sync: Literal["ddp", "allreduce"] = "ddp"
    """Several processes: 'ddp' wraps the model in DistributedDataParallel (the step function
    must call ``ctx.model(...)``, i.e. the wrapper's forward, once per step); 'allreduce'
    averages the gradients after backward, whatever the step function called."""
    find_unused_parameters: bool = False
    """'ddp' mode: let a step leave some parameters without a gradient (DDP's
    ``find_unused_parameters``), as LISA's steps do (culled bones, pose offsets before their
    refinement starts)."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        check_positive_int(self, "steps")
        for name in ("warmup_steps", "checkpoint_every", "keep_every", "print_every"):
            check_positive_int(self, name, allow_zero=True)
        check_positive_int(self, "log_every")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"seed must be an int, got {self.seed!r}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive finite number, got {self.lr!r}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule must be one of {LR_SCHEDULES}, got "
                             f"{self.lr_schedule!r}")
        if not (isinstance(self.lr_final_factor, (int, float))
                and 0 < self.lr_final_factor <= 1):
            raise ValueError(f"lr_final_factor must be in (0, 1], got {self.lr_final_factor!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {self.optimizer!r}")
        if (len(self.betas) != 2
                or not all(isinstance(b, (int, float)) and 0 <= b < 1 for b in self.betas)):
            raise ValueError(f"betas must be two numbers in [0, 1), got {self.betas!r}")
        if not (isinstance(self.weight_decay, (int, float)) and self.weight_decay >= 0):
            raise ValueError(f"weight_decay must be >= 0, got {self.weight_decay!r}")
        if not (isinstance(self.grad_clip, (int, float)) and self.grad_clip >= 0
                and math.isfinite(self.grad_clip)):
            raise ValueError(f"grad_clip must be >= 0 and finite (0: off), got "
                             f"{self.grad_clip!r}")
        if not isinstance(self.device, str) or not self.device:
            raise ValueError(f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got "
                             f"{self.device!r}")
        if self.grad_sync not in ("ddp", "allreduce"):
            raise ValueError(f"grad_sync must be 'ddp' or 'allreduce', got {self.grad_sync!r}")
        if not isinstance(self.progress, bool):
            raise ValueError(f"progress must be a bool, got {self.progress!r}")


def lr_factor(step: int, config: TrainerConfig) -> float:
    """Learning rate of step ``step`` (0-based) as a fraction of ``config.lr``.

    warm-up: ``(step + 1) / warmup_steps`` for ``step < warmup_steps``, else 1; times the decay
    at progress ``p = step / (steps - 1)``: constant 1, exponential ``f ** p``, cosine
    ``f + (1 - f) (1 + cos(pi p)) / 2`` with ``f = lr_final_factor``.
    """
    warm = (step + 1) / config.warmup_steps if step < config.warmup_steps else 1.0
    progress = min(max(step / max(config.steps - 1, 1), 0.0), 1.0)
    final = config.lr_final_factor
    if config.lr_schedule == "exponential":
        decay = final ** progress
    elif config.lr_schedule == "cosine":
        decay = final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * progress))
    else:
        decay = 1.0
    return warm * decay


def build_optimizer(
    model: nn.Module,
    config: TrainerConfig,
    group_lrs: Mapping[tuple[str, ...], float | None] | None = None,
) -> torch.optim.Optimizer:
    """``config.optimizer`` (Adam, AdamW or SGD with ``config``'s lr, betas and weight decay)
    over the trainable parameters of ``model``.

    group_lrs: {tuple of top-level module names: learning rate (None: ``config.lr``)}: one
        parameter group per tuple, with its own learning rate; the other parameters form the
        first group (with ``config.lr``). None or empty: one group.
    """
    group_lrs = group_lrs or {}
    groups: dict[tuple[str, ...] | None, list[nn.Parameter]] = {None: []}
    for name, param in model.named_parameters():
        if param.requires_grad:
            top = name.split(".")[0]
            key = next((names for names in group_lrs if top in names), None)
            groups.setdefault(key, []).append(param)
    if not any(groups.values()):
        raise ValueError("the model has no trainable parameters")
    param_groups = [{"params": params} if key is None else
                    {"params": params, "lr": group_lrs[key] or config.lr}
                    for key, params in groups.items() if params]
    options = {"lr": config.lr, "weight_decay": config.weight_decay}
    if config.optimizer == "adam":
        return torch.optim.Adam(param_groups, betas=config.betas, **options)
    if config.optimizer == "adamw":
        return torch.optim.AdamW(param_groups, betas=config.betas, **options)
    return torch.optim.SGD(param_groups, momentum=config.betas[0], **options)


def build_scheduler(
    optimizer: torch.optim.Optimizer, config: TrainerConfig
) -> torch.optim.lr_scheduler.LambdaLR:
    """The schedule of ``config``: ``LambdaLR`` with :func:`lr_factor`, stepped once a step."""
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: lr_factor(step, config))
