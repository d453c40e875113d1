"""The population-batched policy interface.

A policy is a fixed network shape; its weights live outside it, as one flat parameter vector per candidate, so that
PGPE (thesis 2.4) can search them. ``params`` of shape ``(P, n)`` holds P candidates; ``obs`` of shape ``(P, B, o)``
holds B environments for each candidate. ``unflatten`` turns the flat vectors into per-layer weight tensors once per
rollout; ``act`` then advances all P × B environments with one batched matrix product per layer.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any

import torch


class Policy(ABC):
    """A network whose weights come from outside, one flat vector per candidate.

    Its first weight tensor's first ``observation_size`` rows multiply the observation; with ``input_bias`` the
    second tensor is that layer's bias.
    """

    input_bias: bool = True

    def __init__(self, observation_size: int, action_size: int, shapes: list[tuple[int, ...]]):
        self.observation_size = observation_size
        self.action_size = action_size
        self.shapes = shapes
        self.sizes = [math.prod(shape) for shape in shapes]
        self.num_params = sum(self.sizes)

    def unflatten(self, params: torch.Tensor) -> list[torch.Tensor]:
        """Split ``params`` of shape (P, n) into one (P, *shape) view per weight tensor."""
        if params.ndim != 2 or params.shape[1] != self.num_params:
            raise ValueError(f"params must have shape (P, {self.num_params}), got {tuple(params.shape)}")
        pieces = torch.split(params, self.sizes, dim=1)
        return [piece.reshape(params.shape[0], *shape) for piece, shape in zip(pieces, self.shapes, strict=True)]

    def fold_input(self, params: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
        """Parameters (P, n) that act on an observation o as ``params`` act on (o − mean) / std: the first layer's
        input rows divided by std, and the shift moved into its bias. Without an input bias only the scaling folds,
        so the policy acts as on o / std."""
        folded = params.clone()
        width = self.shapes[0][1]
        rows = folded[:, : self.observation_size * width].view(len(params), self.observation_size, width)
        rows /= std.to(rows)[:, None]
        if self.input_bias:
            folded[:, self.sizes[0] : self.sizes[0] + width] -= mean.to(rows) @ rows
        return folded

    def initial_state(self, population: int, batch: int, device: torch.device | str = "cpu") -> Any:
        """The memory at the start of P × B fresh episodes, on ``device``; None for feed-forward policies."""
        return None

    @abstractmethod
    def act(self, weights: list[torch.Tensor], obs: torch.Tensor, state: Any) -> tuple[torch.Tensor, Any]:
        """Map ``obs`` (P, B, o) to raw actions (P, B, a); the environment adapter bounds them."""

    @abstractmethod
    def initial_center(self, generator: torch.Generator | None = None) -> torch.Tensor:
        """A starting mean μ for the search, shape (n,)."""
