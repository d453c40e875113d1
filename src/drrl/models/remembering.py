"""The world model's memory beside what the policy observes (World Models' controller, Ha & Schmidhuber 2018).

A policy that reads only the observation must see the state in it; from frames it barely does (a move of a fraction
of a pixel between two frames carries the velocities, ``drrl.models.frames``), and a partially observed task hides
part of it by design. The recurrent world model, trained to predict many steps ahead (overshooting, 3.3.2), has to
carry that part in its hidden state. With ``model_based.policy_memory`` the policy reads [o_t, h_{t−1}]: the
observation and the model's last layer's hidden state after reading o_0 … o_{t−1} and a_0 … a_{t−1} (zero at an
episode's first step). Imagined episodes hand the policy the same pair (``ImaginedEnv``, where h is the state the
imagination runs on); ``Remembering`` gives it in reality by stepping the model beside the real env.

Beyond the thesis, whose policies read the observation alone. The memory's meaning moves as the model is refitted;
the search, which runs after every fit, follows it.
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space

from drrl.models.data import model_actions
from drrl.models.recurrent import WorldModel


def memory_space(observation_size: int, model: WorldModel) -> spaces.Box:
    """The space of [observation, memory]: unbounded float32, as imagined observations are."""
    bound = np.finfo(np.float32).max
    return spaces.Box(-bound, bound, (observation_size + model.hidden[-1],), np.float32)


class Remembering(VectorWrapper):
    """A real vector env whose observations are [o_t, h_{t−1}]: ``model`` (one member) reads each observation and
    action as the env is stepped. One episode a sub-environment, as drrl's rollouts run them: an ended episode's
    memory goes on from its last step until the next reset."""

    def __init__(self, env: VectorEnv, model: WorldModel):
        super().__init__(env)
        if len(model) != 1:
            raise ValueError(f"the policy can read the memory of one model, not of an ensemble of {len(model)}")
        self.model = model
        self.single_observation_space = memory_space(int(np.prod(env.single_observation_space.shape or ())), model)
        self.observation_space = batch_space(self.single_observation_space, env.num_envs)
        self._observation: np.ndarray | None = None
        self._state: list[torch.Tensor] = []

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        self._observation, self._state = observation, self.model.initial_state(self.num_envs)
        return self._with_memory(observation), info

    @torch.inference_mode()
    def step(self, actions):
        if self._observation is None:
            raise RuntimeError("call reset() before step()")
        device = self.model.device
        _, self._state = self.model.step(
            torch.as_tensor(self._observation, dtype=torch.float32, device=device).reshape(self.num_envs, -1),
            torch.as_tensor(model_actions(actions, self.env.single_action_space), device=device),
            self._state,
        )
        observation, reward, terminated, truncated, info = self.env.step(actions)
        self._observation = observation
        return self._with_memory(observation), reward, terminated, truncated, info

    def _with_memory(self, observation: np.ndarray) -> np.ndarray:
        memory = self.model.memory(self._state)[0].cpu().numpy()
        return np.concatenate([np.asarray(observation, dtype=np.float32).reshape(self.num_envs, -1), memory], axis=1)
