"""What the optimiser sees when: the warm-up and cosine learning rate, and its scaling with the batch."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from hupbench.training.run_config import OptimConfig


def warmup_cosine(optimizer: torch.optim.Optimizer, total_steps: int, warmup_steps: int = 100,
                  final_lr_fraction: float = 0.02) -> torch.optim.lr_scheduler.LambdaLR:
    """Linear warm-up over ``warmup_steps`` (at most a tenth of the run's ``total_steps``) to the base learning
    rate, then cosine decay to ``final_lr_fraction`` of it at the last step (values checked by
    :class:`hupbench.training.run_config.OptimConfig`)."""
    assert total_steps >= 1 and 0.0 <= final_lr_fraction <= 1.0, (total_steps, final_lr_fraction)
    warmup = min(warmup_steps, total_steps // 10)

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        progress = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return final_lr_fraction + (1.0 - final_lr_fraction) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)


def learning_rate(optim: OptimConfig, global_batch: int) -> float:
    """The optimiser's learning rate for a global batch of ``global_batch`` images.

    ``optim.reference_batch`` null: ``optim.optimizer.lr`` as given. A number N: linear scaling
    (Goyal et al. 2017, "Accurate, large minibatch SGD"), lr x global batch / N, which the
    scheduler's linear warm-up makes safe in the first steps.
    """
    lr = optim.optimizer.keywords["lr"]
    return lr if optim.reference_batch is None else lr * global_batch / optim.reference_batch
