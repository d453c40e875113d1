"""Gymnasium's classic-control tasks compiled by Numba (``pip install "drrl[numba]"``): the same episodes as
Gymnasium's own envs, stepped in the caller's thread for well under a microsecond an env.

Each task is a module of its own that follows Gymnasium's equations and its order of floating-point operations, so
a slot steps as Gymnasium's env would, bit for bit (tests/test_compiled_envs.py runs both side by side): a run on
this engine is the run on the ``gymnasium`` engine, only faster. A task module offers

* ``start(rng)``: one episode's first state and observation, drawn from ``rng`` as Gymnasium's reset draws them;
* ``advance(state, action)``: a Numba function that steps one state in place and returns (reward, terminated);
* ``observe(state, observation)``: a Numba function that writes the state's observation.

``CompiledEpisodes`` runs them over its slots: one compiled loop steps every running episode, leaves an ended one
where it ended (reward 0, its end flags kept, as ``drrl.envs.slots``) and cuts episodes at the id's time limit.
Only the ids as registered are made: a keyword argument (another gravity, Acrobot's "nips" dynamics) is the
gymnasium engine's work.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Sequence
from types import ModuleType
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from drrl.envs.slots import slot_seeds

TASKS = {
    "Acrobot-v1": "acrobot",
    "CartPole-v1": "cartpole",
    "MountainCar-v0": "mountain_car",
    "MountainCarContinuous-v0": "continuous_mountain_car",
    "Pendulum-v1": "pendulum",
}


def installed() -> bool:
    return importlib.util.find_spec("numba") is not None


def ships(env_id: str) -> bool:
    """Whether ``env_id`` is one of the compiled tasks."""
    return env_id in TASKS


def task_module(env_id: str) -> ModuleType:
    """The module that compiles ``env_id`` (imported on first use: importing Numba takes a moment)."""
    return importlib.import_module(f"drrl.envs.compiled.{TASKS[env_id]}")


class CompiledEpisodes(VectorEnv):
    """``num_envs`` episodes of ``env_id``, one a slot, each idle once it ends until the next reset."""

    metadata = {"autoreset_mode": AutoresetMode.DISABLED}

    def __init__(self, env_id: str, num_envs: int):
        from drrl.envs.compiled.loop import step_running

        self._task = task_module(env_id)
        self._step = step_running(self._task.advance, self._task.observe)
        spec = gymnasium.spec(env_id)
        reference = gymnasium.make(env_id, disable_env_checker=True)  # Gymnasium's own spaces
        self.num_envs = num_envs
        self.single_observation_space = reference.observation_space
        self.single_action_space = reference.action_space
        reference.close()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._horizon = spec.max_episode_steps or np.iinfo(np.int64).max
        action_space = self.single_action_space
        self._action_dtype = np.int64 if isinstance(action_space, spaces.Discrete) else np.float32
        self._choices = int(action_space.n) if isinstance(action_space, spaces.Discrete) else 0
        self._action_shape = (num_envs, *(action_space.shape or ()))
        self._rngs: list[np.random.Generator | int] = [np.random.default_rng() for _ in range(num_envs)]
        self._states = np.zeros((num_envs, self._task.STATE_SIZE))
        self._observations = np.zeros((num_envs, *(self.single_observation_space.shape or ())), np.float32)
        self._rewards = np.zeros(num_envs)
        self._terminated = np.zeros(num_envs, dtype=bool)
        self._truncated = np.zeros(num_envs, dtype=bool)
        self._elapsed = np.zeros(num_envs, dtype=np.int64)
        self._started = False

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode in every slot; ``seed`` as in ``drrl.envs.slots.slot_seeds``. A seeded slot starts as
        Gymnasium's env reset with that seed would, an unseeded one goes on from its generator."""
        drawn: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # slots of one seed share a start: drawn once
        for i, slot_seed in enumerate(slot_seeds(seed, self.num_envs)):
            if slot_seed is None:
                self._states[i], self._observations[i] = self._task.start(self._generator(i))
                continue
            if slot_seed not in drawn:
                drawn[slot_seed] = self._task.start(np.random.default_rng(slot_seed))
            self._states[i], self._observations[i] = drawn[slot_seed]
            self._rngs[i] = slot_seed
        self._terminated[:] = False
        self._truncated[:] = False
        self._elapsed[:] = 0
        self._started = True
        return self._observations.copy(), {}

    def _generator(self, slot: int) -> np.random.Generator:
        """Slot ``slot``'s generator; after a seeded reset it is made when first needed, past that reset's draw."""
        rng = self._rngs[slot]
        if not isinstance(rng, np.random.Generator):
            rng = np.random.default_rng(rng)
            self._task.start(rng)
            self._rngs[slot] = rng
        return rng

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step the slots whose episode runs; an ended one returns its last observation, reward 0 and its end flags."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=self._action_dtype)
        if self._choices and (actions.min() < 0 or actions.max() >= self._choices):
            raise ValueError(f"actions must be in 0..{self._choices - 1}, got {actions.tolist()}")
        self._step(
            self._states,
            actions.reshape(self._action_shape),
            self._horizon,
            self._elapsed,
            self._observations,
            self._rewards,
            self._terminated,
            self._truncated,
        )
        return (
            self._observations.copy(),
            self._rewards.copy(),
            self._terminated.copy(),
            self._truncated.copy(),
            {},
        )
