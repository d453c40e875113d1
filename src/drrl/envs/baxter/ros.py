"""A real Baxter as a ``drrl.envs.baxter.robot.Robot``, through ROS: ``BaxterReachEnv(robot=RosBaxter())``.

The robot is reached through rosbridge (``roslaunch rosbridge_server rosbridge_websocket.launch`` on a machine of the
robot's ROS network) with the ``roslibpy`` client, ``pip install "drrl[ros]"``; drrl needs no ROS installation of its
own. It uses the topics of Rethink Robotics' SDK:

* ``/robot/joint_states`` (sensor_msgs/JointState): joint angles and velocities, by joint name (``right_s0``, ...);
* ``/robot/limb/<side>/joint_command`` (baxter_core_msgs/JointCommand): velocity commands at the control rate, and
  position commands to go to a start pose or to hold one (Baxter's controller stops a limb whose commands stop
  arriving, a further guard);
* ``/robot/limb/<side>/collision_detection_state`` (baxter_core_msgs/CollisionDetectionState): the robot's own
  collision detection, the contact rule of reward 5.10 together with the table rule of ``task.touches_table``;
* ``/robot/set_super_enable`` (std_msgs/Bool): enables the motors at the start.

End-points come from the measured joint angles through ``drrl.envs.baxter.kinematics``, the same numbers as the
simulation. The clock is this process's (``time.monotonic``): a step sends its command, sleeps to the end of the
control period (a whole period if it is late) and reads the latest joint state. ``topic`` and ``clock`` can be
given, so that the same class runs against the simulator in the tests.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from drrl.envs.baxter.kinematics import arms_points
from drrl.envs.baxter.model import ARM, SIDES
from drrl.envs.baxter.task import CONTROL_PERIOD, touches_table

JOINT_STATES = "/robot/joint_states", "sensor_msgs/JointState"
COMMAND = "/robot/limb/{side}/joint_command", "baxter_core_msgs/JointCommand"
COLLISION = "/robot/limb/{side}/collision_detection_state", "baxter_core_msgs/CollisionDetectionState"
ENABLE = "/robot/set_super_enable", "std_msgs/Bool"
POSITION_MODE, VELOCITY_MODE = 1, 2  # baxter_core_msgs/JointCommand's modes
START_TOLERANCE = 0.01  # rad: a start pose is reached when every joint is this close ...
START_SPEED = 0.02  # rad/s: ... and moves slower than this
START_TIMEOUT = 15.0  # seconds to reach a start pose before giving up


class Topic(Protocol):
    """What ``RosBaxter`` needs of a ROS topic (``roslibpy.Topic`` has it)."""

    def subscribe(self, callback: Callable[[dict], None]) -> None: ...

    def publish(self, message: Any) -> None: ...


class Clock(Protocol):
    def monotonic(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


def rosbridge_topics(host: str, port: int) -> Callable[[str, str], Topic]:
    """A connection to rosbridge at ``host``:``port``, as a function (name, message type) -> topic."""
    try:
        import roslibpy
    except ImportError:
        raise ImportError('a real Baxter needs the roslibpy client: pip install "drrl[ros]"') from None
    ros = roslibpy.Ros(host=host, port=port)
    ros.run()  # raises if rosbridge does not answer
    return lambda name, message_type: roslibpy.Topic(ros, name, message_type)


class RosBaxter:
    """One real Baxter with ``arms`` moving, commanded every ``control_period`` seconds through rosbridge."""

    num_robots = 1

    def __init__(
        self,
        arms: tuple[str, ...] = SIDES,
        host: str = "localhost",
        port: int = 9090,
        control_period: float = CONTROL_PERIOD,
        topic: Callable[[str, str], Topic] | None = None,
        clock: Clock = time,
    ) -> None:
        self.arms, self.control_period, self._clock = tuple(arms), control_period, clock
        topic = topic or rosbridge_topics(host, port)
        self.names = [f"{side}_{joint.name}" for side in self.arms for joint in ARM]
        self._commands = {side: topic(COMMAND[0].format(side=side), COMMAND[1]) for side in self.arms}
        self._collisions = dict.fromkeys(self.arms, False)
        self._positions: dict[str, float] = {}
        self._velocities: dict[str, float] = {}
        topic(*JOINT_STATES).subscribe(self._read_joint_states)
        for side in self.arms:
            topic(COLLISION[0].format(side=side), COLLISION[1]).subscribe(functools.partial(self._read_collision, side))
        topic(*ENABLE).publish({"data": True})
        self._targets = np.zeros((1, len(self.arms), 3))
        self._stopped, self._tick = True, self._clock.monotonic()
        self._hold: np.ndarray | None = None

    @property
    def qpos(self) -> np.ndarray:
        return self._joints(self._positions)

    @property
    def qvel(self) -> np.ndarray:
        return self._joints(self._velocities)

    @property
    def targets(self) -> np.ndarray:
        return self._targets

    @property
    def end_points(self) -> np.ndarray:
        return arms_points(self.qpos, self.arms)[:, :, 3]

    @property
    def in_contact(self) -> np.ndarray:
        return np.array([any(self._collisions.values())]) | touches_table(arms_points(self.qpos, self.arms))

    def restart(self, ids: np.ndarray, qpos: np.ndarray, targets: np.ndarray) -> None:
        """Go to the start pose ``qpos`` (1, joints) in position mode and wait there at rest."""
        self._targets = np.array(targets, dtype=np.float64).reshape(1, len(self.arms), 3)
        deadline = self._clock.monotonic() + START_TIMEOUT
        while not self._at_rest(qpos[0]):
            if self._clock.monotonic() > deadline:
                raise RuntimeError(f"Baxter did not reach its start pose within {START_TIMEOUT} s")
            self._send(POSITION_MODE, qpos[0])
            self._wait()
        self._stopped = False

    def step(self, velocities: np.ndarray) -> None:
        """Send the joint velocities (1, joints), or hold still once stopped, then wait out the control period."""
        if self._stopped:
            if self._hold is not None:
                self._send(POSITION_MODE, self._hold)
        else:
            self._send(VELOCITY_MODE, velocities[0])
        self._wait()

    def stop(self, ids: np.ndarray) -> None:
        """Hold the joints where they are, in position mode, until the next restart."""
        self._stopped, self._hold = True, self.qpos[0].copy()
        self._send(POSITION_MODE, self._hold)

    # ------------------------------------------------------------------------------------------------ internals

    def _read_collision(self, side: str, message: dict) -> None:
        self._collisions[side] = bool(message["collision_state"])

    def _read_joint_states(self, message: dict) -> None:
        for name, position, velocity in zip(message["name"], message["position"], message["velocity"], strict=False):
            self._positions[name], self._velocities[name] = position, velocity

    def _joints(self, values: dict[str, float]) -> np.ndarray:
        missing = [name for name in self.names if name not in values]
        if missing:
            raise RuntimeError(f"no joint state read yet for {', '.join(missing)} (is /robot/joint_states published?)")
        return np.array([[values[name] for name in self.names]])

    def _at_rest(self, qpos: np.ndarray) -> bool:
        if not all(name in self._positions for name in self.names):
            return False
        return bool(np.all(np.abs(self.qpos[0] - qpos) <= START_TOLERANCE) and np.all(np.abs(self.qvel) < START_SPEED))

    def _send(self, mode: int, values: np.ndarray) -> None:
        for k, side in enumerate(self.arms):
            joints = slice(7 * k, 7 * (k + 1))
            command = {"mode": mode, "command": [float(v) for v in values[joints]], "names": self.names[joints]}
            self._commands[side].publish(command)

    def _wait(self) -> None:
        """Sleep to the end of this control period; a late step (or the first after a pause) waits one whole period
        from now instead of catching up, so that every command acts for a period before the state is read."""
        now = self._clock.monotonic()
        on_time = now <= self._tick + self.control_period
        self._tick = (self._tick if on_time else now) + self.control_period
        self._clock.sleep(self._tick - now)
