"""What a generation's evaluation needs, and the interface every evaluation backend offers.

A backend evaluates all P candidates of a generation for E episodes each and returns one :class:`Evaluation`.
Episode seeds come from the seed it is given (the run seed and the generation), never from where a candidate
ran, so every backend returns the same numbers bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

from drrl.policies.base import Policy
from drrl.rollout.evaluate import Evaluation

BACKENDS = ("local", "ray")


@dataclass(frozen=True)
class Workload:
    """``popsize`` candidates of ``policy``, ``episodes`` episodes each, on env ``env_id`` cut at ``max_steps``."""

    policy: Policy
    env_id: str
    popsize: int
    episodes: int
    max_steps: int | None = None


class Backend(Protocol):
    """Evaluates a generation's candidates."""

    def evaluate(self, params: torch.Tensor, seed: int) -> Evaluation:
        """Each of the P candidates ``params`` (P, n) over the workload's episodes, starts drawn from ``seed``."""

    def close(self) -> None:
        """Release envs and workers."""


def make_backend(name: str, workload: Workload, address: str | None = None, workers: int | None = None) -> Backend:
    """The ``local`` backend (this process) or the ``ray`` one (actors on a Ray cluster at ``address``)."""
    if name == "local":
        if address is not None or workers is not None:
            raise ValueError("--address and --workers are for --backend ray")
        from drrl.rollout.local import LocalBackend

        return LocalBackend(workload)
    if name == "ray":
        try:
            from drrl.rollout.ray import RayBackend
        except ImportError as error:
            raise ValueError(str(error)) from None
        return RayBackend(workload, address=address, workers=workers)
    raise ValueError(f"unknown backend {name!r}; choose one of: {', '.join(BACKENDS)}")


def chunk_bounds(popsize: int, chunks: int) -> list[tuple[int, int]]:
    """``chunks`` consecutive (start, stop) ranges covering ``range(popsize)``, sizes differing by at most one."""
    size, extra = divmod(popsize, chunks)
    edges = [i * size + min(i, extra) for i in range(chunks + 1)]
    return list(zip(edges[:-1], edges[1:]))
