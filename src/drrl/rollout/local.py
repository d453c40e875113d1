"""The local backend: all candidates in one batched rollout in this process."""

from __future__ import annotations

import torch

from drrl.rollout.backend import Workload
from drrl.rollout.evaluate import Evaluation, evaluate
from drrl.rollout.memory import retain_freed_memory


class LocalBackend:
    """One batched env of P·E sub-environments, made once and reused every generation.

    Raises this process's malloc thresholds (``retain_freed_memory``).
    """

    def __init__(self, workload: Workload):
        retain_freed_memory()
        self.workload = workload
        self.env = workload.env.make(workload.popsize * workload.episodes)

    def use(self, workload: Workload) -> None:
        env = workload.env.make(workload.popsize * workload.episodes)
        self.env.close()
        self.workload, self.env = workload, env

    def evaluate(self, params: torch.Tensor, seed: int) -> Evaluation:
        work = self.workload
        return evaluate(
            work.policy, params, self.env, work.episodes, seed=seed, max_steps=work.max_steps, moments=work.moments
        )

    def close(self) -> None:
        self.env.close()
