"""The Baxter reach environments (thesis 5.2): joint angles and velocities in, joint angular velocities out.

``BaxterReachVectorEnv`` is drrl's native batched env (``gymnasium.make_vec``), ``BaxterReachEnv`` the single one
(``gymnasium.make``); both run the physics of ``drrl.envs.baxter.simulation`` and the task of
``drrl.envs.baxter.task``. An action is one angular velocity per joint in rad/s, in a Box bounded by the joints'
velocity limits; actions beyond them are clipped to them (drrl's ActionMap already maps policy outputs onto the
Box), while actions of the wrong shape or with NaN or infinite entries raise ValueError.

The envs reach their robots only through ``drrl.envs.baxter.robot.Robot``: drrl's MuJoCo simulation unless a
``robot`` is given, e.g. a real Baxter (``drrl.envs.baxter.ros.RosBaxter``), which then runs the same task.

Observation (see ReachTask.observe): joint angles (rad), joint velocities as fractions of their limits, each target
(m, base frame) and each end-point-to-target offset (in 0.1 m); for two arms the right arm's entries come first in
each group.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drrl.envs.baxter.model import TIMESTEP, load_model
from drrl.envs.baxter.native import NativeBaxterEnv, OneBaxterEnv
from drrl.envs.baxter.robot import Robot
from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.standin import Actuation, StandIn
from drrl.envs.baxter.task import CONTROL_PERIOD, ReachTask

SUBSTEPS = round(CONTROL_PERIOD / TIMESTEP)  # physics steps per control period


class BaxterReachVectorEnv(NativeBaxterEnv):
    """``num_envs`` Baxters reaching together, stepped on MuJoCo's thread pool, with next-step autoreset and the
    seeding of ``drrl.envs.baxter.native.NativeBaxterEnv``.

    Task options (``arms``, ``targets``, ``reward``, ``action_noise``, ...) are those of ``ReachTask``. ``stand_in``
    (a ``StandIn`` or its keyword arguments) makes every robot of the batch that stand-in for the real Baxter.
    ``info["distance"]`` holds each env's largest end-point-to-target distance (m) after the step. ``width``,
    ``height`` and ``shadows`` set the rgb_array frames (shadows and reflections cost about 5× the frame time).
    ``robot``: the robots to run the task on (``drrl.envs.baxter.robot.Robot``, one per env, moving the task's arms
    at its control period); drrl's simulation unless given. An env that ends stops its robot (``Robot.stop``).
    """

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        task: ReachTask | None = None,
        threads: int | None = None,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        stand_in: StandIn | dict | None = None,
        robot: Robot | None = None,
        **task_options: Any,
    ) -> None:
        super().__init__(num_envs, render_mode, {"width": width, "height": height, "shadows": shadows})
        self.task = task if task is not None else ReachTask(**task_options)
        self.stand_in = StandIn(**stand_in) if isinstance(stand_in, dict) else stand_in
        arms, self._actuation = self.task.arms, None
        if robot is not None:
            self.robot = _checked_robot(robot, num_envs, arms, self.stand_in)
        elif self.stand_in is None:
            self.robot = BaxterBatch(num_envs, arms, SUBSTEPS, threads)
        else:
            model = self.stand_in.model(load_model(arms), arms)
            self.robot = BaxterBatch(num_envs, arms, SUBSTEPS, threads, model)
            self._actuation = Actuation(self.stand_in, num_envs, self.task.num_joints, CONTROL_PERIOD)
        if self.task.controller == "joint_targets":
            self._use_spaces(self.task.observation_size, -np.ones(self.task.num_joints), np.ones(self.task.num_joints))
        else:
            self._use_spaces(self.task.observation_size, -self.task.max_velocity, self.task.max_velocity)

    def _start(self, ids: np.ndarray) -> None:
        joints, targets = self.task.starts(self._random.uniform(ids, self.task.random_numbers_per_start))
        self.robot.restart(ids, joints, targets)
        if self._actuation is not None:
            self._actuation.restart(ids)

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Physics and reward of one control period: (reward, terminated, truncated, info), each (n,)."""
        limit = self.task.max_velocity
        velocities = self.task.velocities(actions, self.robot.qpos)
        if self.task.action_noise:
            noise = self._random.normal(np.arange(self.num_envs), self.task.num_joints)
            velocities = velocities + self.task.action_noise * limit * noise
        velocities = np.clip(velocities, -limit, limit)
        self.robot.step(velocities if self._actuation is None else self._actuation(velocities))
        self.elapsed_steps += 1
        distances = self._distances()
        failed = self.robot.in_contact | self.task.at_limit(self.robot.qpos)
        reward, terminated = self.task.rewards(distances, failed, self.elapsed_steps)
        truncated = self.elapsed_steps >= self.task.horizon
        if (terminated | truncated).any():
            self.robot.stop(np.flatnonzero(terminated | truncated))
        return reward, terminated, truncated, {"distance": distances.max(axis=1)}

    def _info(self) -> dict[str, np.ndarray]:
        return {"distance": self._distances().max(axis=1)}

    def _distances(self) -> np.ndarray:
        return np.linalg.norm(self.robot.targets - self.robot.end_points, axis=2)

    def _observe(self) -> np.ndarray:
        qpos, qvel = self.robot.qpos, self.robot.qvel
        if self.stand_in is not None:  # what the robot's joint sensors read
            ids, joints = np.arange(self.num_envs), self.task.num_joints
            qpos = qpos + self.stand_in.angle_noise * self._random.normal(ids, joints)
            qvel = qvel + self.stand_in.velocity_noise * self._random.normal(ids, joints)
        return self.task.observe(qpos, qvel, self.robot.targets, self.robot.end_points)


def _checked_robot(robot: Robot, num_envs: int, arms: tuple[str, ...], stand_in: StandIn | None) -> Robot:
    """``robot`` if it can run the task: one robot per env, the task's arms moving, the task's control period."""
    if stand_in is not None:
        raise ValueError("stand_in makes drrl's simulation a stand-in robot; give either stand_in or robot")
    if robot.num_robots != num_envs or tuple(robot.arms) != arms:
        raise ValueError(
            f"the env needs {num_envs} robot(s) moving {arms}; the robot given has {robot.num_robots} moving "
            f"{tuple(robot.arms)}"
        )
    if not np.isclose(robot.control_period, CONTROL_PERIOD):
        raise ValueError(
            f"the reach task is commanded every {CONTROL_PERIOD} s (its horizon counts control steps); the robot "
            f"given is commanded every {robot.control_period} s"
        )
    return robot


class BaxterReachEnv(OneBaxterEnv):
    """A single Baxter: the vector env's physics and task for one env, without autoreset; ``robot``, e.g. a real
    Baxter, runs it instead of the simulation.

    ``reset(seed=s)`` gives the same episode as env i of a vector env reset with ``seed=[..., s, ...]``.
    """

    def __init__(
        self,
        render_mode: str | None = None,
        task: ReachTask | None = None,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        robot: Robot | None = None,
        **task_options: Any,
    ) -> None:
        super().__init__(
            BaxterReachVectorEnv(
                1,
                render_mode,
                task,
                threads=1,
                width=width,
                height=height,
                shadows=shadows,
                robot=robot,
                **task_options,
            )
        )
