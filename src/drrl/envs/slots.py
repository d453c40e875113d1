"""Vector envs that run one episode in each sub-environment and then leave it be, so that no step is wasted.

drrl evaluates all of a generation's episodes in one batch, one episode a slot, and stops counting an episode once it
has ended (``drrl.rollout.evaluate``). An engine that steps its sub-environments apart (Gymnasium's envs in turn,
EnvPool's C++ threads) need not step an ended one at all: here it stays where it ended, reward 0 and its end flags
kept, until the next reset. Every sub-environment step computed is then a step counted; Gymnasium's own vector envs
instead restart an ended env and step it on (its autoreset), which on episodes of uneven length computed about eight
steps for every one counted. Gymnasium calls this autoreset mode DISABLED: the caller resets.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space


class EpisodeSlots(VectorEnv):
    """``num_envs`` sub-environments, each running one episode from its reset and idle once it ends.

    Subclasses start episodes (``start``) and step running sub-environments (``advance``).
    """

    metadata = {"autoreset_mode": AutoresetMode.DISABLED}

    def __init__(self, num_envs: int, observation_space: spaces.Space, action_space: spaces.Space):
        self.num_envs = num_envs
        self.single_observation_space = observation_space
        self.single_action_space = action_space
        self.observation_space = batch_space(observation_space, num_envs)
        self.action_space = batch_space(action_space, num_envs)
        self._observations: np.ndarray | None = None
        self._terminated = np.zeros(num_envs, dtype=bool)
        self._truncated = np.zeros(num_envs, dtype=bool)

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode in every sub-environment, seeded as ``slot_seeds`` says."""
        self._observations = np.array(
            self.start(slot_seeds(seed, self.num_envs)), dtype=self.single_observation_space.dtype
        )
        self._terminated[:] = False
        self._truncated[:] = False
        return self._observations.copy(), {}

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step the sub-environments whose episode runs; an ended one returns its last observation, reward 0 and
        the end flags it ended with."""
        if self._observations is None:
            raise RuntimeError("call reset() before step()")
        running = np.flatnonzero(~(self._terminated | self._truncated))
        rewards = np.zeros(self.num_envs)
        if running.size:
            observations, rewards[running], terminated, truncated = self.advance(running, np.asarray(actions)[running])
            self._observations[running] = observations
            self._terminated[running] = terminated
            self._truncated[running] = truncated
        return self._observations.copy(), rewards, self._terminated.copy(), self._truncated.copy(), {}

    @abstractmethod
    def start(self, seeds: list[int | None]) -> np.ndarray:
        """Reset every sub-environment, sub-environment i with ``seeds[i]``; their first observations."""

    @abstractmethod
    def advance(self, slots: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step sub-environments ``slots`` (ascending) with ``actions`` (one row each): observations, rewards,
        terminated and truncated, in the order of ``slots``."""


def slot_seeds(seed: int | Sequence[int] | None, num_envs: int) -> list[int | None]:
    """Each of ``num_envs`` slots' reset seed from ``seed``: None (go on from the current generators), one int
    (slot i gets seed + i, as in Gymnasium's vector envs) or one seed each."""
    if seed is None or isinstance(seed, (int, np.integer)):
        return [None if seed is None else int(seed) + i for i in range(num_envs)]
    seeds: list[int | None] = [int(s) for s in seed]
    if len(seeds) != num_envs:
        raise ValueError(f"expected one seed per env ({num_envs}), got {len(seeds)}")
    return seeds
