"""What a generation's evaluation needs, and the interface every evaluation backend offers.

A backend evaluates all P candidates of a generation for E episodes each and returns one ``Evaluation``.
Episode seeds come from the seed it is given (the run seed and the generation), never from where a candidate
ran, so every backend returns the same numbers bit for bit. The workload names its environment by an
``EnvSource`` (a registered id, or a learned model's weights and settings) that every worker rebuilds, and
``Backend.use`` points a backend at another workload, as the model-based loop does after each fit.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Protocol

import torch

from drrl.envs.batch import EnvSource, RegisteredEnv
from drrl.policies.base import Policy
from drrl.rollout.evaluate import Evaluation


@dataclass(frozen=True)
class Workload:
    """``popsize`` candidates of ``policy``, ``episodes`` episodes each, on ``env`` (a source, or a registered id)
    cut at ``max_steps``; with ``moments``, the observations' sums come back too."""

    policy: Policy
    env: EnvSource  # a str is taken as a registered id: RegisteredEnv(env)
    popsize: int
    episodes: int
    max_steps: int | None = None
    moments: bool = False

    def __post_init__(self):
        if isinstance(self.env, str):
            object.__setattr__(self, "env", RegisteredEnv(self.env))


class Backend(Protocol):
    """Evaluates a generation's candidates."""

    def evaluate(self, params: torch.Tensor, seed: int) -> Evaluation:
        """Each of the P candidates ``params`` (P, n) over the workload's episodes, starts drawn from ``seed``."""

    def use(self, workload: Workload) -> None:
        """Evaluate ``workload`` from now on (same popsize and episodes, another env or policy)."""

    def close(self) -> None:
        """Release envs and workers."""


def chunk_bounds(popsize: int, chunks: int) -> list[tuple[int, int]]:
    """``chunks`` consecutive (start, stop) ranges covering ``range(popsize)``, sizes differing by at most one."""
    size, extra = divmod(popsize, chunks)
    edges = [i * size + min(i, extra) for i in range(chunks + 1)]
    return list(itertools.pairwise(edges))
