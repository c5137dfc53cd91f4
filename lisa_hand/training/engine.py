"""The generic training loop behind ``lisa train-prior`` and ``lisa train``.

The engine knows nothing about hands: it runs a *step function* that samples its data and
returns its losses, and takes care of everything around it::

    def step_fn(ctx: StepContext) -> dict[str, torch.Tensor]:
        idx = torch.randint(num_items, (batch,), generator=ctx.generator)  # same on every rank
        x, y = shard((inputs[idx], targets[idx]), ctx.dist)              # this rank's slice
        pred = ctx.model(x.to(ctx.device))                               # through DDP
        data = global_mean(((pred - y.to(ctx.device)) ** 2).sum(-1), batch, ctx.dist)
        prior = unwrap(ctx.model).codes.pow(2).mean()  # same on every rank: no scaling
        return {"total": data + 1e-4 * prior, "data": data, "prior": prior}

    result = train(model, step_fn, TrainerConfig(steps=1000), out_dir, run_config=full_config)

Around each step: backward, gradient averaging over ranks, optional clipping, a NaN/inf guard
on every loss term and the gradients, the optimizer and LR-schedule steps, a JSON-lines log and
a tqdm bar (rank 0). Around the run: the resolved config saved into the run folder, atomic
checkpoints every ``checkpoint_every`` steps and at the end, automatic resume from
``out_dir/last.pt``, and a graceful stop on Ctrl-C / SIGTERM (finish the step, checkpoint, return).

Exact resume: the data must be drawn only from ``ctx.generator`` (and torch/numpy/python global
RNGs, which are checkpointed too) and may depend on ``ctx.step``, never on wall-clock time or on
state outside the checkpoint. Then "run 100 steps" equals "run 60, kill -9, resume to 100" (bit
for bit on CPU).

Several processes: launch with ``torchrun``; every rank draws the same global batch from the
generator and keeps its slice (``distributed.shard``); see ``distributed`` for the loss scaling.

Beside this module: the loop's settings, optimizer and schedule in ``training.config``, the step
checks and NaN guard in ``training.guard``, the log and progress bar in ``training.progress``,
the Ctrl-C / SIGTERM handling in ``training.stop``, checkpoint writing in ``training.checkpoint``.
"""

from __future__ import annotations

import os
import random
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from ..model.checkpoint import LAST_CHECKPOINT, Checkpoint, load_checkpoint
from ..utils.config import config_to_dict, save_config
from ..utils.io import ensure_writable_dir
from .checkpoint import (
    capture_rng_state,
    check_finite_state,
    copy_checkpoint,
    remove_stale_temporaries,
    restore_rng_state,
    save_checkpoint,
)
from .config import TrainerConfig, build_optimizer, build_scheduler
from .distributed import (
    DistContext,
    allreduce_gradients,
    broadcast_module,
    cleanup,
    gather_objects,
    init_distributed,
    wrap_ddp,
)
from .guard import check_finite_step, check_step_output
from .progress import Progress, RunLog
from .stop import StopRequest

__all__ = [
    "StepContext",
    "StepInfo",
    "TrainResult",
    "StepFn",
    "Hook",
    "Trainer",
    "train",
    "seed_everything",
    "CONFIG_FILE",
]

CONFIG_FILE = "config.json"
"""The run's resolved config, written into the run folder at start."""


@dataclass
class StepContext:
    """What a step function gets."""

    step: int
    """0-based index of this step (the number of steps completed before it)."""
    num_steps: int
    """Total steps of the run."""
    generator: torch.Generator
    """The engine's data generator (CPU, checkpointed): draw every random batch from it. It is
    in the same state on every rank, so every rank draws the same global batch."""
    model: nn.Module
    """The model to call: the DistributedDataParallel wrapper with several processes in 'ddp'
    mode, else the model itself. ``distributed.unwrap(ctx.model)`` is always the bare model."""
    device: torch.device
    """Device of the model; move the batch there."""
    dist: DistContext
    """Rank and world size (for ``distributed.shard`` and ``distributed.global_mean``)."""


StepFn = Callable[[StepContext], Mapping[str, "torch.Tensor | float"]]
"""``step_fn(ctx) -> {"total": scalar tensor to minimise, other terms: scalars for the log}``."""


@dataclass
class StepInfo:
    """What a hook gets after each completed step (on every rank)."""

    step: int
    """0-based index of the completed step (``step + 1`` steps are done)."""
    losses: dict[str, float]
    """Loss terms of the step, averaged over ranks (= over the global batch)."""
    lr: float
    """Learning rate of the step (first parameter group)."""
    grad_norm: float
    """Global gradient norm before clipping."""
    checkpoint: Path | None
    """Checkpoint written right after this step (rank 0's path on every rank), else None."""
    trainer: Trainer
    """The trainer (model, optimizer, out_dir, ``save()``)."""


Hook = Callable[[StepInfo], None]


@dataclass
class TrainResult:
    """How a run ended."""

    status: Literal["completed", "interrupted"]
    """'completed' (all steps done) or 'interrupted' (Ctrl-C / SIGTERM: checkpointed, stopped)."""
    steps_done: int
    """Number of completed steps (a resumed run counts the steps before the resume too)."""
    start_step: int
    """Steps already done when this call started (0 for a fresh run)."""
    losses: dict[str, float]
    """Loss terms of the last step run by this call (empty if none ran)."""
    checkpoint: Path | None
    """Last checkpoint written by this call, or None."""
    resumed_from: Path | None
    """Checkpoint the run resumed from, or None."""
    seconds: float
    """Wall-clock time of the steps of this call."""

    @property
    def steps_per_second(self) -> float:
        """Training speed of this call."""
        ran = self.steps_done - self.start_step
        return ran / self.seconds if self.seconds > 0 else 0.0


def seed_everything(seed: int) -> None:
    """Seed torch (CPU and CUDA), numpy's global generator and python's ``random``."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _flat_diff(a: Any, b: Any, prefix: str = "") -> list[str]:
    """Dotted keys where two nested dicts differ (for the resume note)."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = list(dict.fromkeys([*a, *b]))
        out = []
        for key in keys:
            out += _flat_diff(a.get(key), b.get(key), f"{prefix}.{key}" if prefix else key)
        return out
    return [] if a == b else [prefix or "<root>"]


_FRESH_KEYS_SKIPPED = ("params", "initial_lr", "lr")
"""Keys of a parameter group that the resume does not copy from the freshly built optimizer:
the parameters, and the learning rates, which come from the schedule's base rates."""


def _group_settings(optimizer: torch.optim.Optimizer) -> list[dict[str, Any]]:
    """The hyperparameters of each parameter group (betas, weight decay, ...), without the
    parameters and the learning rates."""
    return [{key: value for key, value in group.items() if key not in _FRESH_KEYS_SKIPPED}
            for group in optimizer.param_groups]


def _apply_optimizer_settings(optimizer: torch.optim.Optimizer, scheduler: Any,
                              fresh_groups: list[dict[str, Any]],
                              fresh_base_lrs: list[float]) -> list[str]:
    """After loading a checkpoint's optimizer and scheduler states, put back this run's
    settings where they differ: each group's hyperparameters (``fresh_groups``) and the
    schedule's base learning rates (``fresh_base_lrs``), and the rate of the current step
    (``LambdaLR``: ``base_lr * lr_lambda(step)`` with this run's lambdas; other schedules: scaled
    by the ratio of the base rates). -> one ``"name old -> new"`` per change (empty: none)."""
    changed: list[str] = []
    groups = optimizer.param_groups
    for index, (group, fresh) in enumerate(zip(groups, fresh_groups, strict=False)):
        where = f" (group {index})" if len(groups) > 1 else ""
        for key, value in fresh.items():
            if key in group and group[key] != value:
                changed.append(f"{key}{where} {group[key]} -> {value}")
                group[key] = value
    base_lrs = getattr(scheduler, "base_lrs", None)
    if not fresh_base_lrs or base_lrs is None or len(base_lrs) != len(fresh_base_lrs):
        return changed
    is_lambda = isinstance(scheduler, torch.optim.lr_scheduler.LambdaLR)
    for index, (group, old, new) in enumerate(zip(groups, list(base_lrs), fresh_base_lrs,
                                                  strict=False)):
        if old != new:
            where = f" (group {index})" if len(groups) > 1 else ""
            changed.append(f"lr{where} {old:g} -> {new:g}")
            scheduler.base_lrs[index] = new
            group["initial_lr"] = new
        if is_lambda:
            # The rate of this step under this run's schedule (its lambdas are rebuilt from
            # this run's config; unchanged settings give the checkpoint's rate bit for bit).
            group["lr"] = new * scheduler.lr_lambdas[index](scheduler.last_epoch)
        elif old != new:
            group["lr"] = group["lr"] * new / old
    if hasattr(scheduler, "_last_lr"):
        scheduler._last_lr = [group["lr"] for group in groups]
    return changed


class Trainer:
    """One training run: owns the device placement, optimizer, schedule, data generator, files.

    Construct on every rank (under torchrun), then call ``run()``. Files (config, log,
    checkpoints) are written by rank 0 only, into ``out_dir``:

    - ``config.json``: ``run_config`` (or the ``TrainerConfig``) resolved, written at start;
    - ``log.jsonl``: one line per logged step;
    - ``last.pt``: the latest checkpoint; ``step_XXXXXXXX.pt`` copies with ``keep_every``.

    Args:
        model: the module to train (moved to the device; its parameters are what is checkpointed).
        step_fn: ``step_fn(ctx: StepContext) -> {"total": tensor, ...}``.
        config: the loop settings.
        out_dir: the run folder.
        run_config: the full resolved config (a dataclass) of the run, saved to ``config.json``
            and into every checkpoint (to rebuild the model later); default ``config``.
        optimizer_fn: ``optimizer_fn(model) -> Optimizer`` (per-group learning rates, ...),
            called after the model is on its device; default: ``config.optimizer``.
        scheduler_fn: ``scheduler_fn(optimizer) -> LRScheduler`` stepped once per step;
            default: ``LambdaLR`` with ``lr_factor``.
        resume: True: continue from ``out_dir/last.pt`` if it exists; False: start afresh
            (overwriting the folder's checkpoints and log); a path: continue from that file.
        hooks: ``hook(info: StepInfo)`` called after every step on every rank (validation,
            previews; rank-0-only work should test ``info.trainer.dist.is_main``).
        extra_state: a dict, or a function returning one, stored in every checkpoint
            (``Checkpoint.extra``); after a resume ``trainer.resumed_extra`` holds the loaded one.
        dist: a ready ``DistContext``; default: ``init_distributed(config.device)`` (torchrun's
            environment, else one process).
        name: the command its notes are printed as (``lisa train: resuming ...``).
    """

    def __init__(
        self,
        model: nn.Module,
        step_fn: StepFn,
        config: TrainerConfig,
        out_dir: str | os.PathLike,
        *,
        run_config: Any = None,
        optimizer_fn: Callable[[nn.Module], torch.optim.Optimizer] | None = None,
        scheduler_fn: Callable[[torch.optim.Optimizer], Any] | None = None,
        resume: bool | str | os.PathLike = True,
        hooks: Sequence[Hook] = (),
        extra_state: Mapping[str, Any] | Callable[[], Mapping[str, Any]] | None = None,
        dist: DistContext | None = None,
        name: str = "lisa train",
    ) -> None:
        if not isinstance(model, nn.Module):
            raise TypeError(f"model must be a torch.nn.Module, got {type(model).__name__}")
        if not callable(step_fn):
            raise TypeError("step_fn must be callable: step_fn(ctx: StepContext) -> dict")
        if not isinstance(config, TrainerConfig):
            raise TypeError(f"config must be a TrainerConfig, got {type(config).__name__}")
        self.config = config
        self.name = name
        self.step_fn = step_fn
        self.out_dir = Path(out_dir)
        self.run_config = run_config if run_config is not None else config
        self.hooks = list(hooks)
        self.extra_state = extra_state
        self.resumed_extra: dict[str, Any] = {}
        self._owns_dist = dist is None
        self.dist = dist if dist is not None else init_distributed(config.device)
        self.device = self.dist.device
        self.last_path = self.out_dir / LAST_CHECKPOINT
        try:
            if self.dist.is_main:
                ensure_writable_dir(self.out_dir)
                remove_stale_temporaries(self.last_path)

            self.model = model.to(self.device)
            self.optimizer = (optimizer_fn(self.model) if optimizer_fn is not None
                              else build_optimizer(self.model, config))
            self.scheduler = (scheduler_fn(self.optimizer) if scheduler_fn is not None
                              else build_scheduler(self.optimizer, config))
            self.generator = torch.Generator().manual_seed(config.seed)
            self.step = 0
            self.resumed_from = self._resume(resume)
            if self.resumed_from is None:
                seed_everything(config.seed + self.dist.rank)
            # Every rank starts from rank 0's weights (DDP also does this when wrapping).
            broadcast_module(self.model, self.dist)
            use_ddp = self.dist.is_distributed and config.grad_sync == "ddp"
            self.wrapped = wrap_ddp(
                self.model, self.dist,
                find_unused_parameters=config.find_unused_parameters) if use_ddp else self.model
        except BaseException:
            if self._owns_dist:
                cleanup(self.dist)
            raise
        self._stop = StopRequest(self._note)
        self._last_checkpoint: Path | None = None
        self._saved_step = self.step if self.resumed_from is not None else -1

    # --------------------------------------------------------------------------------------------
    # resume

    def _resume(self, resume: bool | str | os.PathLike) -> Path | None:
        if resume is True:
            exists = self.last_path.is_file()
            if len(set(gather_objects(exists, self.dist))) > 1:
                raise ValueError(f"{self.last_path}: some ranks see this checkpoint and others "
                                 "do not; the run folder must be on a filesystem shared by "
                                 "every node")
            path = self.last_path if exists else None
        elif resume is False or resume is None:
            path = None
        else:
            path = Path(resume)
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such checkpoint to resume from")
        if path is None:
            return None
        ckpt = load_checkpoint(path)
        try:
            self.model.load_state_dict(ckpt.model)
        except RuntimeError as exc:
            first = str(exc).strip().splitlines()
            raise ValueError(f"{path}: the checkpoint does not fit the model "
                             f"({' '.join(line.strip() for line in first[:3])})") from None
        fresh_groups = _group_settings(self.optimizer)
        fresh_base_lrs = list(getattr(self.scheduler, "base_lrs", []))
        try:
            if ckpt.optimizer is not None:
                self.optimizer.load_state_dict(ckpt.optimizer)
            if ckpt.scheduler is not None and hasattr(self.scheduler, "load_state_dict"):
                self.scheduler.load_state_dict(ckpt.scheduler)
        except (ValueError, KeyError, RuntimeError) as exc:
            raise ValueError(f"{path}: the optimizer/scheduler state does not fit "
                             f"({exc})") from None
        changed = _apply_optimizer_settings(self.optimizer, self.scheduler, fresh_groups,
                                            fresh_base_lrs)
        if changed:
            self._note(f"resuming {path} at step {ckpt.step} with this run's optimizer "
                       f"settings, not the checkpoint's: {'; '.join(changed)} (the learning-"
                       "rate schedule continues from this step at the new rate)")
        generators = {"data": self.generator}
        if len(ckpt.rng) == self.dist.world_size:
            restore_rng_state(ckpt.rng[self.dist.rank], generators)
        elif ckpt.rng:
            # Another number of processes: the data generator (identical on every rank)
            # continues exactly; per-rank global RNGs cannot, so they are reseeded.
            restore_rng_state(ckpt.rng[0], generators)
            seed_everything(self.config.seed + self.dist.rank + 7919 * ckpt.step)
            self._note(f"{path} was written by {len(ckpt.rng)} process(es), this run has "
                       f"{self.dist.world_size}: the data stream continues exactly, the "
                       "per-process random state is reseeded")
        self.step = ckpt.step
        self.resumed_extra = ckpt.extra
        new_config = config_to_dict(self.run_config)
        if ckpt.config is not None and ckpt.config != new_config:
            keys = _flat_diff(ckpt.config, new_config)
            self._note(f"resuming {path} with a changed config: {', '.join(keys[:10])}")
        return path

    def _note(self, message: str) -> None:
        if self.dist.is_main:
            print(f"{self.name}: {message}", file=sys.stderr, flush=True)

    # --------------------------------------------------------------------------------------------
    # checkpoints

    def save(self) -> Path:
        """Checkpoint the current state to ``out_dir/last.pt`` (and a kept copy) now.

        Collective: call it on every rank; when it returns, the file is written (rank 0 writes
        it) and every rank gets its path. Raises ``NonFiniteError``
        (writing nothing) when a parameter is NaN/inf, and ``RuntimeError`` when the ranks'
        weights disagree (a 'ddp' step function that bypassed ``ctx.model``).
        """
        model_state = self.model.state_dict()
        # Every rank checks its own (identical) weights so that all ranks raise together.
        check_finite_state(model_state, f"step {self.step}: refusing to write checkpoint "
                                        f"{self.last_path} (the previous one is left intact)")
        self._check_ranks_agree()
        rng = gather_objects(capture_rng_state({"data": self.generator}), self.dist)
        failure: BaseException | None = None
        if self.dist.is_main:
            try:
                self._write_checkpoint(model_state, rng)
            except BaseException as exc:  # re-raised below, after telling the other ranks
                failure = exc
        if self.dist.is_distributed:
            # Rank 0 tells every rank whether the file is written: a barrier (after save()
            # returns, the file exists for every rank) that cannot hang on a failed write.
            import torch.distributed as tdist

            status = torch.tensor([0.0 if failure is not None else 1.0], device=self.device)
            tdist.broadcast(status, src=0)
            if failure is None and status.item() == 0.0:
                raise RuntimeError(f"step {self.step}: rank 0 failed to write the checkpoint "
                                   f"{self.last_path} (see rank 0's error)")
        if failure is not None:
            raise failure
        self._last_checkpoint = self.last_path
        self._saved_step = self.step
        return self.last_path

    def _write_checkpoint(self, model_state: dict[str, torch.Tensor],
                          rng: list[dict[str, Any]]) -> None:
        extra = self.extra_state() if callable(self.extra_state) else self.extra_state
        ckpt = Checkpoint(
            step=self.step,
            model=model_state,
            optimizer=self.optimizer.state_dict(),
            scheduler=(self.scheduler.state_dict()
                       if hasattr(self.scheduler, "state_dict") else None),
            rng=rng,
            config=config_to_dict(self.run_config),
            trainer=config_to_dict(self.config),
            extra=dict(extra or {}),
        )
        save_checkpoint(self.last_path, ckpt)
        if self.config.keep_every and self.step % self.config.keep_every == 0:
            copy_checkpoint(self.last_path, self.out_dir / f"step_{self.step:08d}.pt")

    def _check_ranks_agree(self) -> None:
        if not self.dist.is_distributed:
            return
        import torch.distributed as tdist

        with torch.no_grad():
            total = sum((p.detach().double().sum() for p in self.model.parameters()),
                        torch.zeros((), dtype=torch.float64, device=self.device))
            spread = torch.stack([total, -total])
            tdist.all_reduce(spread, op=tdist.ReduceOp.MAX)
        high, neg_low = spread.tolist()
        if high + neg_low > 1e-9 * max(1.0, abs(high)):
            raise RuntimeError(
                f"step {self.step}: the ranks' weights disagree (sums {-neg_low} .. {high}); in "
                "grad_sync='ddp' mode the step function must call ctx.model(...) (the "
                "DistributedDataParallel wrapper), or use grad_sync='allreduce'")

    # --------------------------------------------------------------------------------------------
    # the loop

    def run(self) -> TrainResult:
        """Train from ``self.step`` to ``config.steps``; return how it ended.

        Raises ``NonFiniteError`` (a ``ValueError``) naming the step and the loss term or the
        parameter when a loss or a gradient is NaN/inf; nothing is written then, so the last
        checkpoint is the last good state.
        """
        try:
            return self._run()
        finally:
            if self._owns_dist:
                cleanup(self.dist)

    def _run(self) -> TrainResult:
        config = self.config
        start = self.step
        if self.dist.is_main:
            save_config(self.out_dir / CONFIG_FILE, self.run_config)
        if start >= config.steps:
            self._note(f"nothing to do: {start} steps done, the run has {config.steps}")
            return TrainResult("completed", start, start, {}, None, self.resumed_from, 0.0)
        if self.resumed_from is not None:
            self._note(f"resuming from {self.resumed_from} at step {start}")

        log = RunLog(self.out_dir, start, self.dist.is_main)
        progress = Progress(config, start, self.dist.is_main)
        params = [p for p in self.model.parameters() if p.requires_grad]
        losses: dict[str, float] = {}
        status: Literal["completed", "interrupted"] = "completed"
        began = time.perf_counter()
        try:
            with self._stop:
                while self.step < config.steps:
                    if self._stop.signal is not None and not self.dist.is_distributed:
                        # One process: a stop requested between steps (e.g. during a hook)
                        # stops before the next step. Several: the request travels with the
                        # next step's collective so that every rank stops after the same step.
                        status = "interrupted"
                        break
                    losses, stop = self._step_and_report(log, progress, began, params)
                    if stop:
                        status = "interrupted"
                        break
        finally:
            progress.close()
            log.close()
        seconds = time.perf_counter() - began
        if status == "interrupted":
            if self._saved_step != self.step:
                self.save()
            self._note(f"stopped at step {self.step}; checkpoint {self._last_checkpoint} "
                       "(run the same command again to resume)")
        return TrainResult(status, self.step, start, losses, self._last_checkpoint,
                           self.resumed_from, seconds)

    def _step_and_report(
        self, log: RunLog, progress: Progress, began: float, params: list[nn.Parameter]
    ) -> tuple[dict[str, float], bool]:
        """One step, then its log line, progress, checkpoint and hooks. -> (losses, stop)."""
        config = self.config
        step = self.step
        losses, lr, grad_norm, stop = self._one_step(step, params)
        self.step = step + 1
        done = self.step
        if done % config.log_every == 0 or done == config.steps:
            log.write({"step": step, "lr": lr, "grad_norm": grad_norm,
                       "seconds": round(time.perf_counter() - began, 4), "losses": losses})
        progress.update(done, losses, lr)
        written = None
        if done == config.steps or (config.checkpoint_every
                                    and done % config.checkpoint_every == 0):
            written = self.save()
        info = StepInfo(step, losses, lr, grad_norm, written, self)
        for hook in self.hooks:
            hook(info)
        return losses, stop

    def _one_step(
        self, step: int, params: list[nn.Parameter]
    ) -> tuple[dict[str, float], float, float, bool]:
        self.model.train()
        self.optimizer.zero_grad(set_to_none=True)
        ctx = StepContext(step, self.config.steps, self.generator, self.wrapped, self.device,
                          self.dist)
        out = self.step_fn(ctx)
        names, values, total = check_step_output(out, step)
        total.backward()
        if self.dist.is_distributed and self.config.grad_sync == "allreduce":
            allreduce_gradients(params, self.dist)
        grads = [p.grad for p in params if p.grad is not None]
        if grads:
            grad_norm = torch.linalg.vector_norm(
                torch.stack([torch.linalg.vector_norm(g.detach(), dtype=torch.float64)
                             for g in grads]))
        else:
            grad_norm = torch.zeros((), dtype=torch.float64, device=self.device)
        stop_flag = 1.0 if self._stop.signal is not None else 0.0
        # One vector, one collective and one device->host copy per step: the losses (averaged
        # over ranks), the gradient norm (identical on every rank) and the stop request.
        vector = torch.cat([
            torch.stack([v.detach().to(self.device, torch.float64) for v in values]),
            grad_norm.to(self.device, torch.float64).reshape(1),
            torch.tensor([stop_flag], dtype=torch.float64, device=self.device),
        ])
        if self.dist.is_distributed:
            import torch.distributed as tdist

            tdist.all_reduce(vector, op=tdist.ReduceOp.SUM)
            vector /= self.dist.world_size
        host = vector.tolist()
        losses = dict(zip(names, host[:-2], strict=True))
        norm, stop = host[-2], host[-1] > 0
        check_finite_step(step, losses, norm, self.model, params,
                          self._last_checkpoint or self.resumed_from)
        if self.config.grad_clip > 0:
            scale = min(1.0, self.config.grad_clip / (norm + 1e-6))
            if scale < 1.0:
                torch._foreach_mul_(grads, scale)
        lr = float(self.optimizer.param_groups[0]["lr"])
        self.optimizer.step()
        self.scheduler.step()
        return losses, lr, norm, stop


def train(
    model: nn.Module,
    step_fn: StepFn,
    config: TrainerConfig,
    out_dir: str | os.PathLike,
    **kwargs: Any,
) -> TrainResult:
    """Build a ``Trainer`` and run it; the keyword arguments are ``Trainer``'s."""
    return Trainer(model, step_fn, config, out_dir, **kwargs).run()
