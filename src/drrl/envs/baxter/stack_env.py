"""The Baxter stacking environments (5.2's wood stacking): ``BaxterStackVectorEnv`` (native batch,
``gymnasium.make_vec``) and ``BaxterStackEnv`` (``gymnasium.make``), on the grasping scene of
``drrl.envs.baxter.grasping`` stepped by ``drrl.envs.baxter.simulation.BaxterBatch``, the task of
``drrl.envs.baxter.stacking``.

``info["stacked"]``: whether the stack stood for one second at this step (the episode then ends);
``info["placed"]``: how many blocks rest on their places.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from drrl.envs.baxter.env import SUBSTEPS
from drrl.envs.baxter.native import NativeBaxterEnv, OneBaxterEnv
from drrl.envs.baxter.render import STACK_VIEW
from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.stacking import HORIZON, SETTLE_STEPS, StackTask


class BaxterStackVectorEnv(NativeBaxterEnv):
    """``num_envs`` Baxters stacking blocks together, stepped on MuJoCo's thread pool, with next-step autoreset and the
    seeding of ``drrl.envs.baxter.native.NativeBaxterEnv``. Task options (``blocks``, ``positions``, ``reward``,
    ``controller``, ``demo_start``, ...) are those of ``StackTask``; ``width``, ``height`` and ``shadows`` set the
    rgb_array frames, seen from close by the blocks.
    """

    view = STACK_VIEW

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
        super().__init__(num_envs, render_mode, {"width": width, "height": height, "shadows": shadows})
        self.task = task if task is not None else StackTask(**task_options)
        self.robot = BaxterBatch(num_envs, self.task.arms, SUBSTEPS, threads, blocks=self.task.blocks)
        self._use_spaces(self.task.observation_size, *self.task.action_bounds)
        self.standing_steps = np.zeros(num_envs, dtype=np.int64)
        self._hand = self.robot.model.body(f"{self.task.side}_hand").id

    def _start(self, ids: np.ndarray) -> None:
        task = self.task
        uniform = self._random.uniform(ids, task.random_numbers_per_start)
        joints, blocks = task.starts(uniform)
        self.robot.restart(ids, joints, np.zeros((len(ids), 0, 3)), blocks)
        if task.demo_start:
            states, lengths = demonstrations(task.arms, task.blocks, task.positions)
            demo = (uniform[:, -2] * len(lengths)).astype(np.int64)
            step = (uniform[:, -1] * task.demo_start * lengths[demo]).astype(np.int64)
            self.robot.restore(ids, states[demo, step])
        self.standing_steps[ids] = 0

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Physics and reward of one control period: (reward, terminated, truncated, info), each (n,)."""
        robot, task = self.robot, self.task
        velocities, openings = task.commands(actions, robot.qpos, self._jacobians)
        robot.step(np.clip(velocities, -task.max_velocity, task.max_velocity), openings)
        self.elapsed_steps += 1
        blocks, touching = robot.blocks, robot.touching
        standing = task.standing(blocks, touching, robot.block_speeds)
        self.standing_steps = np.where(standing, self.standing_steps + 1, 0)
        stacked = self.standing_steps >= SETTLE_STEPS
        failed = robot.in_contact | task.at_limit(robot.qpos)
        progress = (
            task.progress(blocks, touching, robot.grip_points) if task.reward == "dense" else np.zeros(len(blocks))
        )
        reward = task.rewards(standing, progress, failed, self.elapsed_steps)
        truncated = self.elapsed_steps >= task.horizon
        info = {"stacked": stacked & ~failed, "placed": task.placed(blocks[..., :3]).sum(axis=1)}
        return reward, failed | stacked, truncated, info

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

    def _info(self) -> dict[str, np.ndarray]:
        placed = self.task.placed(self.robot.blocks[..., :3]).sum(axis=1)
        return {"stacked": np.zeros(self.num_envs, dtype=bool), "placed": placed}


DEMONSTRATIONS = 16  # recorded episodes of the scripted stacker per task, for starts from demonstrations


@cache
def demonstrations(arms: tuple[str, ...], blocks: int, positions: str) -> tuple[np.ndarray, np.ndarray]:
    """The scripted stacker's episodes on the task (seeds 0–15): every step's whole simulation state (episodes,
    steps, state) and each episode's length up to the step its stack stood (episodes,). Recorded once a process."""
    env = BaxterStackVectorEnv(DEMONSTRATIONS, arms=arms, blocks=blocks, positions=positions, controller="end_point")
    observations, _ = env.reset(seed=list(range(DEMONSTRATIONS)))
    stacker, states = ScriptedStacker(env.task), []
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


class BaxterStackEnv(OneBaxterEnv):
    """A single Baxter stacking: the vector env's physics and task for one env, without autoreset.

    ``reset(seed=s)`` gives the same episode as env i of a vector env reset with ``seed=[..., s, ...]``.
    """

    def __init__(
        self,
        render_mode: str | None = None,
        task: StackTask | None = None,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        **task_options: Any,
    ) -> None:
        super().__init__(
            BaxterStackVectorEnv(
                1, render_mode, task, threads=1, width=width, height=height, shadows=shadows, **task_options
            )
        )
