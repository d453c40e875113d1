"""Running statistics of the observations a policy acted on, for feeding it normalised observations.

Mania et al. (2018, ARS) found that normalising a linear policy's inputs by the mean and standard deviation of every
state seen so far turned random search from failing to competitive on MuJoCo's locomotion tasks; EvoTorch offers
the same. The statistics are summed over all training episodes of a run (no forgetting), in float64. A rollout
keeps one sum per slot, so that however a backend splits the candidates, their sum comes out bit for bit the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

MIN_STD = 1e-8  # an input that never varied is left unscaled


@dataclass(frozen=True)
class Moments:
    """Counts, sums and sums of squares of observations of size o, one row per slot (or one for a whole run)."""

    count: np.ndarray  # (S,) int64
    total: np.ndarray  # (S, o) float64
    squares: np.ndarray  # (S, o) float64

    @staticmethod
    def empty(slots: int, size: int) -> Moments:
        return Moments(np.zeros(slots, dtype=np.int64), np.zeros((slots, size)), np.zeros((slots, size)))

    def add(self, observations: np.ndarray, running: np.ndarray) -> None:
        """Add each running slot's observation (S, o) to its row."""
        seen = np.asarray(observations, dtype=np.float64)
        self.count[running] += 1
        np.add(self.total, seen, out=self.total, where=running[:, None])
        np.add(self.squares, np.square(seen), out=self.squares, where=running[:, None])

    @staticmethod
    def concat(parts: list[Moments]) -> Moments:
        return Moments(
            *(np.concatenate([getattr(part, name) for part in parts]) for name in ("count", "total", "squares"))
        )

    def plus(self, other: Moments) -> Moments:
        """One row: this one (a run's so far) plus the sum of ``other``'s rows."""
        return Moments(
            self.count + other.count.sum(),
            self.total + other.total.sum(axis=0, keepdims=True),
            self.squares + other.squares.sum(axis=0, keepdims=True),
        )

    def mean_std(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and standard deviation over all rows, float32; 0 and 1 before any observation, std 1 where it is
        below 1e-8."""
        count, total, squares = self.count.sum(), self.total.sum(axis=0), self.squares.sum(axis=0)
        if count == 0:
            return torch.zeros(len(total)), torch.ones(len(total))
        mean = total / count
        std = np.sqrt(np.maximum(squares / count - mean**2, 0.0))
        std[std < MIN_STD] = 1.0
        return torch.as_tensor(mean, dtype=torch.float32), torch.as_tensor(std, dtype=torch.float32)

    def state_dict(self) -> dict:
        return {
            "count": torch.as_tensor(self.count),
            "total": torch.as_tensor(self.total),
            "squares": torch.as_tensor(self.squares),
        }

    @staticmethod
    def from_state_dict(state: dict) -> Moments:
        return Moments(
            state["count"].numpy().astype(np.int64),
            state["total"].numpy().astype(np.float64),
            state["squares"].numpy().astype(np.float64),
        )
