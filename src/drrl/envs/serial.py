"""Gymnasium's envs, one per slot, stepped in turn: the engine for any registered id, with nothing else installed.

The same envs and seeds as Gymnasium's ``SyncVectorEnv``, so the same episodes, but an ended episode's env is not
stepped again (``EpisodeSlots``). An env that observes discrete values or tuples of them (FrozenLake's cell,
Blackjack's hand) is seen through Gymnasium's ``FlattenObservation``: a Discrete value one-hot, parts concatenated.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import FlattenObservation

from drrl.envs.registry import lookup
from drrl.envs.slots import EpisodeSlots

# observation spaces flattened into one 1-D Box, a Discrete value one-hot
FLATTENED = (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary, spaces.Tuple, spaces.Dict)


def make_env(env_id: str, options: Mapping[str, Any] | None = None) -> gymnasium.Env:
    """``gymnasium.make(env_id, **options)``, its observations flattened into a 1-D Box if they are discrete or
    composite (a Box of any shape is left as it is: frames are read by a model-based run)."""
    env = gymnasium.make(env_id, disable_env_checker=True, **(options or {}))
    return FlattenObservation(env) if isinstance(env.observation_space, FLATTENED) else env


class SerialEpisodes(EpisodeSlots):
    """``num_envs`` copies of ``make_env(env_id, options)``."""

    def __init__(self, env_id: str, num_envs: int, options: Mapping[str, Any] | None = None):
        lookup(env_id)  # registers a family's id (drrl.envs.registry) in this process, a worker's too
        self.envs = []
        try:
            for _ in range(num_envs):
                self.envs.append(make_env(env_id, options))
        except BaseException:
            self.close_extras()
            raise
        super().__init__(num_envs, self.envs[0].observation_space, self.envs[0].action_space)

    def start(self, seeds):
        return np.stack([env.reset(seed=seed)[0] for env, seed in zip(self.envs, seeds, strict=True)])

    def advance(self, slots, actions):
        observations, rewards, terminated, truncated = zip(
            *(self.envs[i].step(action)[:4] for i, action in zip(slots, actions, strict=True)), strict=True
        )
        return (
            np.stack(observations),
            np.asarray(rewards, dtype=np.float64),
            np.asarray(terminated, dtype=bool),
            np.asarray(truncated, dtype=bool),
        )

    def close_extras(self, **kwargs):
        for env in self.envs:
            env.close()
