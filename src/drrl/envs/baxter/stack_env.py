"""The Baxter stacking environments (5.2's wood stacking): ``BaxterStackVectorEnv`` (native batch,
``gymnasium.make_vec``) and ``BaxterStackEnv`` (``gymnasium.make``), on the grasping scene of
``drrl.envs.baxter.grasping`` stepped by ``drrl.envs.baxter.simulation.BaxterBatch``, the task of
``drrl.envs.baxter.stacking``.

``info["stacked"]``: whether the stack stood for one second at this step (the episode then ends);
``info["placed"]``: how many blocks rest on their places.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from drrl.envs.baxter.env import _METADATA, SUBSTEPS, _check_render_mode, _checked, _Randomness
from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.stacking import HORIZON, SETTLE_STEPS, StackTask

if TYPE_CHECKING:
    from drrl.envs.baxter.render import SceneRenderer


def _spaces(task: StackTask) -> tuple[spaces.Box, spaces.Box]:
    bound = np.finfo(np.float32).max
    low, high = task.action_bounds
    return (
        spaces.Box(-bound, bound, (task.observation_size,), np.float32),
        spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32),
    )


class BaxterStackVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` Baxters stacking blocks together, stepped on MuJoCo's thread pool, with next-step autoreset.

    Seeding as ``drrl.envs.baxter.env.BaxterReachVectorEnv``: one int for the batch, or one per env. Task options
    (``blocks``, ``positions``, ``reward``, ``controller``, ...) are those of ``StackTask``.
    """

    metadata = {**_METADATA, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        task: StackTask | None = None,
        threads: int | None = None,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        **task_options: Any,
    ) -> None:
        self.num_envs = num_envs
        self.render_mode = _check_render_mode(render_mode)
        self._render_options: dict[str, Any] = {"width": width, "height": height, "shadows": shadows}
        self.task = task if task is not None else StackTask(**task_options)
        self.robot = BaxterBatch(num_envs, self.task.arms, SUBSTEPS, threads, blocks=self.task.blocks)
        self.single_observation_space, self.single_action_space = _spaces(self.task)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.elapsed_steps = np.zeros(num_envs, dtype=np.int64)
        self.standing_steps = np.zeros(num_envs, dtype=np.int64)
        self._randomness: _Randomness | None = None
        self._ended = np.zeros(num_envs, dtype=bool)
        self._renderer: SceneRenderer | None = None
        self._hand = self.robot.model.body(f"{self.task.side}_hand").id

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env afresh (``seed`` as ``BaxterReachVectorEnv.reset``; ``options`` are not used)."""
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
            self._randomness = _Randomness(batch=self.np_random)
        elif seed is not None:
            if len(seed) != self.num_envs:
                raise ValueError(f"expected one seed per env ({self.num_envs}), got {len(seed)}")
            self._randomness = _Randomness(per_env=[np.random.default_rng(int(s)) for s in seed])
        elif self._randomness is None:
            self._randomness = _Randomness(batch=self.np_random)
        self._start(np.arange(self.num_envs))
        return self._observe(), self._info(np.zeros(self.num_envs, dtype=bool))

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control period for every env; envs that ended on the previous step restart instead (reward 0)."""
        if self._randomness is None:
            raise RuntimeError("call reset() before step()")
        actions = _checked(actions, (self.num_envs, self.task.action_size))
        reward, terminated, truncated, stacked = self._advance(actions)
        restarting = self._ended.nonzero()[0]
        if restarting.size:
            self._start(restarting)
            reward[restarting] = 0.0
            terminated[restarting] = truncated[restarting] = stacked[restarting] = False
        self._ended = terminated | truncated
        return self._observe(), reward, terminated, truncated, self._info(stacked)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB frame per env, or None without render_mode 'rgb_array'."""
        if self.render_mode is None or self._randomness is None:
            return None
        if self._renderer is None:
            from drrl.envs.baxter.render import STACK_VIEW, SceneRenderer

            self._renderer = SceneRenderer(self.robot.model, view=STACK_VIEW, **self._render_options)
        return tuple(self._renderer.render(self.robot.data(i)) for i in range(self.num_envs))

    def close(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close(**kwargs)

    # ------------------------------------------------------------------------------------------------ internals

    def _start(self, ids: np.ndarray) -> None:
        assert self._randomness is not None
        task = self.task
        uniform = self._randomness.uniform(ids, task.random_numbers_per_start)
        joints, blocks = task.starts(uniform)
        self.robot.restart(ids, joints, np.zeros((len(ids), 0, 3)), blocks)
        if task.demo_start:
            states, lengths = demonstrations(task.arms, task.blocks, task.positions)
            demo = (uniform[:, -2] * len(lengths)).astype(np.int64)
            step = (uniform[:, -1] * task.demo_start * lengths[demo]).astype(np.int64)
            self.robot.restore(ids, states[demo, step])
        self.elapsed_steps[ids] = self.standing_steps[ids] = 0
        self._ended[ids] = False

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Physics and reward of one control period: (reward, terminated, truncated, stacked), each (n,)."""
        robot, task = self.robot, self.task
        velocities, openings = task.commands(actions, robot.qpos, self._jacobians)
        robot.step(np.clip(velocities, -task.max_velocity, task.max_velocity), openings)
        self.elapsed_steps += 1
        blocks, touching = robot.blocks, robot.touching
        standing = task.standing(blocks, touching, robot.block_speeds)
        self.standing_steps = np.where(standing, self.standing_steps + 1, 0)
        stacked = self.standing_steps >= SETTLE_STEPS
        failed = robot.in_contact | task.at_limit(robot.qpos)
        reward = task.rewards(standing, task.progress(blocks, touching, robot.grip_points), failed, self.elapsed_steps)
        terminated = failed | stacked
        truncated = self.elapsed_steps >= task.horizon
        return reward, terminated, truncated, stacked & ~failed

    def _jacobians(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The grip point's Jacobian over the arm's joints (n, 6, 7), the gripper's frame (n, 3, 3), the point
        (n, 3)."""
        points = self.robot.grip_points[:, 0]
        translation, rotation = self.robot.batch.jac(self._hand, points)
        dofs = self.robot.dofs
        jacobian = np.concatenate([translation[..., dofs], rotation[..., dofs]], axis=1)
        return jacobian, self.robot.grip_frames[:, 0], points

    def _observe(self) -> np.ndarray:
        robot = self.robot
        return self.task.observe(robot.qpos, robot.qvel, robot.openings, robot.grip_points, robot.blocks)

    def _info(self, stacked: np.ndarray) -> dict[str, Any]:
        return {"stacked": stacked, "placed": self.task.placed(self.robot.blocks[..., :3]).sum(axis=1)}


DEMONSTRATIONS = 16  # recorded episodes of the scripted stacker per task, for starts from demonstrations


@cache
def demonstrations(arms: tuple[str, ...], blocks: int, positions: str) -> tuple[np.ndarray, np.ndarray]:
    """The scripted stacker's episodes on the task (seeds 0–15): every step's whole simulation state (episodes,
    steps, state) and each episode's length up to the step its stack stood (episodes,). Recorded once a process."""
    env = BaxterStackVectorEnv(DEMONSTRATIONS, arms=arms, blocks=blocks, positions=positions, controller="end_point")
    observations, _ = env.reset(seed=list(range(DEMONSTRATIONS)))
    stacker, states = ScriptedStacker(env.task, DEMONSTRATIONS), []
    lengths = np.zeros(DEMONSTRATIONS, dtype=np.int64)
    for step in range(1, HORIZON + 1):
        states.append(env.robot.states())
        observations, _, terminated, _, info = env.step(stacker.act(observations))
        lengths = np.where(info["stacked"] & (lengths == 0), step, lengths)
        if terminated.any() and not info["stacked"][terminated].all():
            raise RuntimeError("the scripted stacker failed while recording demonstrations")
        if (lengths > 0).all():
            break
    env.close()
    if (lengths == 0).any():
        raise RuntimeError("the scripted stacker did not build every demonstration's stack within the horizon")
    return np.stack(states, axis=1), lengths


class BaxterStackEnv(gym.Env):
    """A single Baxter stacking: the vector env's physics and task for one env, without autoreset.

    ``reset(seed=s)`` gives the same episode as env i of a vector env reset with ``seed=[..., s, ...]``.
    """

    metadata = _METADATA

    def __init__(
        self,
        render_mode: str | None = None,
        task: StackTask | None = None,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        **task_options: Any,
    ) -> None:
        self._vector = BaxterStackVectorEnv(
            1, render_mode, task, threads=1, width=width, height=height, shadows=shadows, **task_options
        )
        self.render_mode = self._vector.render_mode
        self.task = self._vector.task
        self.observation_space = self._vector.single_observation_space
        self.action_space = self._vector.single_action_space

    @property
    def robot(self) -> BaxterBatch:
        return self._vector.robot

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._vector._randomness = _Randomness(per_env=[self.np_random])
        self._vector._start(np.zeros(1, dtype=np.int64))
        return self._vector._observe()[0], _first(self._vector._info(np.zeros(1, dtype=bool)))

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._vector._randomness is None:
            raise RuntimeError("call reset() before step()")
        action = _checked(action, (self.task.action_size,))
        reward, terminated, truncated, stacked = self._vector._advance(action[None])
        info = _first(self._vector._info(stacked))
        return self._vector._observe()[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), info

    def render(self) -> np.ndarray | None:
        frames = self._vector.render()
        return None if frames is None else frames[0]

    def close(self) -> None:
        self._vector.close()


def _first(info: dict[str, Any]) -> dict[str, Any]:
    return {key: value[0].item() for key, value in info.items()}
