"""The boundary between the reach task and a Baxter, simulated or real: ``Robot``.

The reach envs (``drrl.envs.baxter.env``) reach their robots only through this interface, at the control rate:

* ``restart(ids, qpos, targets)``: bring robots ``ids`` to rest at the start joint angles, with their targets;
* ``step(velocities)``: send one joint-velocity command per joint (rad/s, thesis 5.2.1), hold it for one control
  period and read the new state; the call returns once the period has passed: the simulation computes it, a real
  robot waits on its clock;
* ``qpos``, ``qvel`` (n, joints): the joint angles (rad) and velocities (rad/s) read at the last step;
  ``end_points`` (n, arms, 3): the gripper end-points, base frame; ``in_contact`` (n,): whether an arm touches
  anything; ``targets`` (n, arms, 3): what ``restart`` set;
* ``stop(ids)``: the safety stop, sent when an episode ends (a failure or the horizon): the robots hold still and
  ignore commands until their next ``restart``.

drrl's simulation (``drrl.envs.baxter.simulation.BaxterBatch``, n Baxters in MuJoCo) is one such robot;
``drrl.envs.baxter.ros.RosBaxter`` (one real Baxter through ROS) is another, so that
``BaxterReachEnv(robot=RosBaxter(...))`` is the same Gymnasium env, task, reward and failure rule on the real robot.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Robot(Protocol):
    """n Baxters with ``arms`` moving, commanded every ``control_period`` seconds (see the module docstring)."""

    @property
    def num_robots(self) -> int: ...

    @property
    def arms(self) -> tuple[str, ...]: ...

    @property
    def control_period(self) -> float: ...

    @property
    def qpos(self) -> np.ndarray: ...

    @property
    def qvel(self) -> np.ndarray: ...

    @property
    def targets(self) -> np.ndarray: ...

    @property
    def end_points(self) -> np.ndarray: ...

    @property
    def in_contact(self) -> np.ndarray: ...

    def restart(self, ids: np.ndarray, qpos: np.ndarray, targets: np.ndarray) -> None: ...

    def step(self, velocities: np.ndarray) -> None: ...

    def stop(self, ids: np.ndarray) -> None: ...
