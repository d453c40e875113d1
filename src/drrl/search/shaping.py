"""Fitness shaping: what PGPE sees of the returns before it estimates a gradient.

"none" keeps the raw returns, as the thesis does (2.31–2.33). "centered_ranks" replaces them by their ranks mapped
linearly onto [-0.5, 0.5], which makes the step independent of the scale of the returns and robust to outliers.
"""

from __future__ import annotations

import torch

FITNESS_SHAPINGS = ("none", "centered_ranks")


def centered_ranks(fitness: torch.Tensor) -> torch.Tensor:
    """Ranks of ``fitness`` (P,) mapped linearly to [-0.5, 0.5]: the worst gets -0.5, the best +0.5.

    Tied values share the average of their ranks, so two candidates with the same return get the same shaped value
    (with symmetric sampling a tied pair then gives no gradient, as it should; a stable order would invent one).
    The result always sums to zero.
    """
    count = fitness.numel()
    if count < 2:
        return torch.zeros_like(fitness)
    values, order = torch.sort(fitness, stable=True)
    _, group, group_size = torch.unique_consecutive(values, return_inverse=True, return_counts=True)
    first_rank = torch.cumsum(group_size, 0) - group_size
    average_rank = first_rank + (group_size - 1) / 2
    ranks = torch.empty_like(fitness)
    ranks[order] = average_rank[group].to(fitness.dtype)
    return ranks / (count - 1) - 0.5


def shape_fitness(fitness: torch.Tensor, shaping: str) -> torch.Tensor:
    """``fitness`` shaped by one of ``FITNESS_SHAPINGS``."""
    if shaping == "none":
        return fitness
    if shaping == "centered_ranks":
        return centered_ranks(fitness)
    raise ValueError(f"unknown fitness shaping {shaping!r}; choose one of: {', '.join(FITNESS_SHAPINGS)}")
