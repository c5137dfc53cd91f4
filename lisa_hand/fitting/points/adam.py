"""The optimiser of the point fit's stages: Adam on a few tensors, and its cosine schedule."""

from __future__ import annotations

import math

import torch

__all__ = ["Adam", "cosine_factor"]


class Adam:
    """Adam (Kingma and Ba 2015) on a few tensors, each with its own learning rate.

    The same update as ``torch.optim.Adam`` with default betas and eps; written out because the
    first ``torch.optim`` optimizer of a process imports ``torch._dynamo`` (seconds, the length
    of a whole fit). ``factor`` scales every learning rate (the schedule).
    groups: (tensor, learning rate) pairs; the tensors are updated in place from their ``.grad``.
    """

    def __init__(self, groups: list[tuple[torch.Tensor, float]], betas=(0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.groups = groups
        self.betas = betas
        self.eps = eps
        self.factor = 1.0
        self.steps = 0
        self.moments = [(torch.zeros_like(t), torch.zeros_like(t)) for t, _ in groups]

    @torch.no_grad()
    def step(self) -> None:
        """Update the tensors from their ``.grad`` (then cleared)."""
        self.steps += 1
        beta1, beta2 = self.betas
        correction1 = 1.0 - beta1**self.steps
        correction2 = 1.0 - beta2**self.steps
        for (tensor, lr), (mean, square) in zip(self.groups, self.moments, strict=True):
            if tensor.grad is None:
                continue
            grad = tensor.grad
            mean.mul_(beta1).add_(grad, alpha=1.0 - beta1)
            square.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
            denominator = (square / correction2).sqrt_().add_(self.eps)
            tensor.addcdiv_(mean, denominator, value=-lr * self.factor / correction1)
            tensor.grad = None

    def select(self, index: torch.Tensor, tensors: list[torch.Tensor]) -> None:
        """Keep the rows ``index`` of every moment and go on with ``tensors`` (the same
        tensors, rows selected, in the order of the groups)."""
        assert len(tensors) == len(self.groups)
        self.groups = [(new, lr) for new, (_, lr) in zip(tensors, self.groups, strict=True)]
        self.moments = [(mean[index], square[index]) for mean, square in self.moments]


def cosine_factor(step: int, total: int, floor: float) -> float:
    """Learning-rate factor at ``step`` of ``total``: cosine from 1 down to ``floor``."""
    if total <= 1:
        return 1.0
    return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * step / (total - 1)))
