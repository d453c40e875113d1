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

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from drrl.envs.baxter.model import TIMESTEP, load_model
from drrl.envs.baxter.robot import Robot
from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.standin import Actuation, StandIn
from drrl.envs.baxter.task import CONTROL_PERIOD, ReachTask

if TYPE_CHECKING:
    from drrl.envs.baxter.render import SceneRenderer

SUBSTEPS = round(CONTROL_PERIOD / TIMESTEP)  # physics steps per control period
_METADATA = {"render_modes": ["rgb_array"], "render_fps": round(1 / CONTROL_PERIOD)}


class _Randomness:
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


def _spaces(task: ReachTask) -> tuple[spaces.Box, spaces.Box]:
    bound = np.finfo(np.float32).max  # the state is bounded, but loosely: keep the checker quiet
    observation = spaces.Box(-bound, bound, (task.observation_size,), np.float32)
    if task.controller == "joint_targets":
        return observation, spaces.Box(-1.0, 1.0, (task.num_joints,), np.float32)
    velocity = task.max_velocity.astype(np.float32)
    return observation, spaces.Box(-velocity, velocity, dtype=np.float32)


def _check_render_mode(render_mode: str | None) -> str | None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    return render_mode


class BaxterReachVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` Baxters reaching together, stepped on MuJoCo's thread pool, with next-step autoreset.

    ``reset(seed=int)`` seeds one generator for all starts, targets and noise of the batch; ``reset(seed=[s_0,
    ...])`` gives env i its own generator ``np.random.default_rng(s_i)``, so that its episodes depend only on s_i.
    Task options (``arms``, ``targets``, ``reward``, ``action_noise``, ...) are those of ``ReachTask``. ``stand_in``
    (a ``StandIn`` or its keyword arguments) makes every robot of the batch that stand-in for the real Baxter.
    ``info["distance"]`` holds each env's largest end-point-to-target distance (m) after the step. ``width``,
    ``height`` and ``shadows`` set the rgb_array frames (shadows and reflections cost about 5× the frame time).
    ``robot``: the robots to run the task on (``drrl.envs.baxter.robot.Robot``, one per env, moving the task's arms
    at its control period); drrl's simulation unless given. An env that ends stops its robot (``Robot.stop``).
    """

    metadata = {**_METADATA, "autoreset_mode": AutoresetMode.NEXT_STEP}

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
        self.num_envs = num_envs
        self.render_mode = _check_render_mode(render_mode)
        self._render_options: dict[str, Any] = {"width": width, "height": height, "shadows": shadows}
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
        self.single_observation_space, self.single_action_space = _spaces(self.task)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.elapsed_steps = np.zeros(num_envs, dtype=np.int64)
        self._randomness: _Randomness | None = None
        self._ended = np.zeros(num_envs, dtype=bool)  # ended on the previous step: restart on this one
        self._renderer: SceneRenderer | None = None

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env afresh. ``seed``: one int for the batch, one int per env, or None to go on drawing from
        the current generator(s). ``options`` are not used."""
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
        return self._observe(), {"distance": self._distances().max(axis=1)}

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control period for every env; envs that ended on the previous step restart instead.

        A restarting env returns its start observation, reward 0, terminated and truncated False; its action is
        ignored (Gymnasium's next-step autoreset). An env failing at step T is both terminated and truncated.
        """
        if self._randomness is None:
            raise RuntimeError("call reset() before step()")
        reward, terminated, truncated, distance = self._advance(
            _checked(actions, (self.num_envs, self.task.num_joints))
        )
        restarting = self._ended.nonzero()[0]
        if restarting.size:
            self._start(restarting)
            reward[restarting] = 0.0
            terminated[restarting] = truncated[restarting] = False
            distance[restarting] = self._distances()[restarting].max(axis=1)
        self._ended = terminated | truncated
        return self._observe(), reward, terminated, truncated, {"distance": distance}

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB frame per env, or None without render_mode 'rgb_array'."""
        if self.render_mode is None or self._randomness is None:
            return None
        if not isinstance(self.robot, BaxterBatch):
            raise ValueError(f"only drrl's simulation renders frames; this env runs on {type(self.robot).__name__}")
        if self._renderer is None:
            from drrl.envs.baxter.render import SceneRenderer

            self._renderer = SceneRenderer(self.robot.model, **self._render_options)
        return tuple(self._renderer.render(self.robot.data(i)) for i in range(self.num_envs))

    def close(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close(**kwargs)

    # ------------------------------------------------------------------------------------------------ internals

    @property
    def _random(self) -> _Randomness:
        if self._randomness is None:
            raise RuntimeError("call reset() before step()")
        return self._randomness

    def _start(self, ids: np.ndarray) -> None:
        joints, targets = self.task.starts(self._random.uniform(ids, self.task.random_numbers_per_start))
        self.robot.restart(ids, joints, targets)
        if self._actuation is not None:
            self._actuation.restart(ids)
        self.elapsed_steps[ids] = 0
        self._ended[ids] = False

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Physics and reward of one control period: (reward, terminated, truncated, largest distance), each (n,)."""
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
        return reward, terminated, truncated, distances.max(axis=1)

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


def _checked(actions, shape: tuple[int, ...]) -> np.ndarray:
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != shape:
        raise ValueError(f"expected actions of shape {shape}, got {actions.shape}")
    finite = np.isfinite(actions)
    if not finite.all():
        bad = np.flatnonzero(~finite.all(axis=-1)).tolist() if actions.ndim == 2 else []
        raise ValueError(f"non-finite actions{f' for envs {bad}' if bad else ''}: {actions[~finite].tolist()}")
    return actions


class BaxterReachEnv(gym.Env):
    """A single Baxter: the vector env's physics and task for one env, without autoreset; ``robot``, e.g. a real
    Baxter, runs it instead of the simulation.

    ``reset(seed=s)`` gives the same episode as env i of a vector env reset with ``seed=[..., s, ...]``.
    """

    metadata = _METADATA

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
        self._vector = BaxterReachVectorEnv(
            1, render_mode, task, threads=1, width=width, height=height, shadows=shadows, robot=robot, **task_options
        )
        self.render_mode = self._vector.render_mode
        self.task = self._vector.task
        self.observation_space = self._vector.single_observation_space
        self.action_space = self._vector.single_action_space

    @property
    def robot(self) -> Robot:
        return self._vector.robot

    @property
    def elapsed_steps(self) -> int:
        return int(self._vector.elapsed_steps[0])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._vector._randomness = _Randomness(per_env=[self.np_random])
        self._vector._start(np.zeros(1, dtype=np.int64))
        return self._vector._observe()[0], {"distance": float(self._vector._distances().max())}

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._vector._randomness is None:
            raise RuntimeError("call reset() before step()")
        action = _checked(action, (self.task.num_joints,))
        reward, terminated, truncated, distance = self._vector._advance(action[None])
        return (
            self._vector._observe()[0],
            float(reward[0]),
            bool(terminated[0]),
            bool(truncated[0]),
            {"distance": float(distance[0])},
        )

    def render(self) -> np.ndarray | None:
        frames = self._vector.render()
        return None if frames is None else frames[0]

    def close(self) -> None:
        self._vector.close()
