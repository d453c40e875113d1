"""What drrl's native Baxter envs share: seeding, next-step autoreset, frames, and the single env over a batch of one.

A task's batch (a ``NativeBaxterEnv``) writes only its own steps: ``_start(ids)`` (new episodes in envs ``ids``),
``_advance(actions)`` (physics and reward of one control period: reward, terminated, truncated and the step's info,
each (n,)), ``_observe()`` and ``_info()`` (the info at the current state, which a restarted env reports).
``OneBaxterEnv`` is one env of such a batch, without autoreset: ``reset(seed=s)`` gives the same episode as env i of
a batch reset with ``seed=[..., s, ...]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.task import CONTROL_PERIOD

if TYPE_CHECKING:
    from drrl.envs.baxter.render import SceneRenderer

METADATA = {"render_modes": ["rgb_array"], "render_fps": round(1 / CONTROL_PERIOD)}


class Randomness:
    """Random numbers per env, from one generator for the whole batch or from each env's own generator (then drawn
    env by env: a Python loop, paid at restarts and, with transition noise, at every step)."""

    def __init__(self, batch: np.random.Generator | None = None, per_env: Sequence[np.random.Generator] = ()) -> None:
        self._batch, self._per_env = batch, per_env

    def uniform(self, ids: np.ndarray, size: int) -> np.ndarray:
        if self._batch is not None:
            return self._batch.random((len(ids), size))
        return np.stack([self._per_env[i].random(size) for i in ids])

    def normal(self, ids: np.ndarray, size: int) -> np.ndarray:
        if self._batch is not None:
            return self._batch.standard_normal((len(ids), size))
        return np.stack([self._per_env[i].standard_normal(size) for i in ids])


class NativeBaxterEnv(gym.vector.VectorEnv):
    """``num_envs`` Baxters of one task, with next-step autoreset (see the module docstring for what a task writes).

    ``reset(seed=int)`` seeds one generator for all starts and noise of the batch; ``reset(seed=[s_0, ...])`` gives
    env i its own generator ``np.random.default_rng(s_i)``, so that its episodes depend only on s_i. ``robot`` is
    what the envs step; frames are drawn from ``view`` (``drrl.envs.baxter.render``) when it is drrl's simulation.
    """

    metadata = {**METADATA, "autoreset_mode": AutoresetMode.NEXT_STEP}
    robot: Any
    task: Any
    view: dict | None = None

    def __init__(self, num_envs: int, render_mode: str | None, render_options: dict[str, Any]) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_envs, self.render_mode, self._render_options = num_envs, render_mode, render_options
        self.elapsed_steps = np.zeros(num_envs, dtype=np.int64)
        self._randomness: Randomness | None = None
        self._ended = np.zeros(num_envs, dtype=bool)  # ended on the previous step: restart on this one
        self._renderer: SceneRenderer | None = None

    def _use_spaces(self, observation_size: int, action_low: np.ndarray, action_high: np.ndarray) -> None:
        """The single and batched spaces: observations of ``observation_size`` (bounded loosely, which keeps
        Gymnasium's checker quiet), actions in the Box from ``action_low`` to ``action_high``."""
        bound = np.finfo(np.float32).max
        self.single_observation_space = spaces.Box(-bound, bound, (observation_size,), np.float32)
        self.single_action_space = spaces.Box(
            np.asarray(action_low, np.float32), np.asarray(action_high, np.float32), dtype=np.float32
        )
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env afresh. ``seed``: one int for the batch, one int per env, or None to go on drawing from
        the current generator(s). ``options`` are not used."""
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
            self._randomness = Randomness(batch=self.np_random)
        elif seed is not None:
            if len(seed) != self.num_envs:
                raise ValueError(f"expected one seed per env ({self.num_envs}), got {len(seed)}")
            self._randomness = Randomness(per_env=[np.random.default_rng(int(s)) for s in seed])
        elif self._randomness is None:
            self._randomness = Randomness(batch=self.np_random)
        self._restart(np.arange(self.num_envs))
        return self._observe(), self._info()

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control period for every env; envs that ended on the previous step restart instead.

        A restarting env returns its start observation, reward 0, terminated and truncated False, and the info of
        its start; its action is ignored (Gymnasium's next-step autoreset).
        """
        self._check_reset()
        actions = checked(actions, (self.num_envs, *(self.single_action_space.shape or ())))
        reward, terminated, truncated, info = self._advance(actions)
        restarting = self._ended.nonzero()[0]
        if restarting.size:
            self._restart(restarting)
            reward[restarting] = 0.0
            terminated[restarting] = truncated[restarting] = False
            for key, value in self._info().items():
                info[key][restarting] = value[restarting]
        self._ended = terminated | truncated
        return self._observe(), reward, terminated, truncated, info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB frame per env, or None without render_mode 'rgb_array'."""
        if self.render_mode is None or self._randomness is None:
            return None
        if not isinstance(self.robot, BaxterBatch):
            raise ValueError(f"only drrl's simulation renders frames; this env runs on {type(self.robot).__name__}")
        if self._renderer is None:
            from drrl.envs.baxter.render import SceneRenderer

            self._renderer = SceneRenderer(self.robot.model, view=self.view, **self._render_options)
        return tuple(self._renderer.render(self.robot.data(i)) for i in range(self.num_envs))

    def close(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close(**kwargs)

    @property
    def _random(self) -> Randomness:
        self._check_reset()
        assert self._randomness is not None
        return self._randomness

    def _check_reset(self) -> None:
        if self._randomness is None:
            raise RuntimeError("call reset() before step()")

    def _restart(self, ids: np.ndarray) -> None:
        self._start(ids)
        self.elapsed_steps[ids] = 0
        self._ended[ids] = False

    def _start(self, ids: np.ndarray) -> None:
        raise NotImplementedError

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        raise NotImplementedError

    def _observe(self) -> np.ndarray:
        raise NotImplementedError

    def _info(self) -> dict[str, np.ndarray]:
        raise NotImplementedError


class OneBaxterEnv(gym.Env):
    """One env of a native batch (``vector``, of one env), without autoreset."""

    metadata = METADATA

    def __init__(self, vector: NativeBaxterEnv) -> None:
        self._vector = vector
        self.render_mode = vector.render_mode
        self.task = vector.task
        self.observation_space = vector.single_observation_space
        self.action_space = vector.single_action_space

    @property
    def robot(self):
        return self._vector.robot

    @property
    def elapsed_steps(self) -> int:
        return int(self._vector.elapsed_steps[0])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._vector._randomness = Randomness(per_env=[self.np_random])
        self._vector._restart(np.zeros(1, dtype=np.int64))
        return self._vector._observe()[0], _first(self._vector._info())

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._vector._check_reset()
        action = checked(action, tuple(self.action_space.shape or ()))
        reward, terminated, truncated, info = self._vector._advance(action[None])
        observation = self._vector._observe()[0]
        return observation, float(reward[0]), bool(terminated[0]), bool(truncated[0]), _first(info)

    def render(self) -> np.ndarray | None:
        frames = self._vector.render()
        return None if frames is None else frames[0]

    def close(self) -> None:
        self._vector.close()


def checked(actions, shape: tuple[int, ...]) -> np.ndarray:
    """``actions`` as float64 of ``shape``; ValueError if of another shape or not finite."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != shape:
        raise ValueError(f"expected actions of shape {shape}, got {actions.shape}")
    finite = np.isfinite(actions)
    if not finite.all():
        bad = np.flatnonzero(~finite.all(axis=-1)).tolist() if actions.ndim == 2 else []
        raise ValueError(f"non-finite actions{f' for envs {bad}' if bad else ''}: {actions[~finite].tolist()}")
    return actions


def _first(info: dict[str, np.ndarray]) -> dict[str, Any]:
    return {key: value[0].item() for key, value in info.items()}
