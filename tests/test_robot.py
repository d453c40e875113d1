"""The boundary to a real Baxter: the reach env through ``Robot``, and ``RosBaxter`` against the simulator."""

from __future__ import annotations

import sys
from collections import defaultdict

import numpy as np
import pytest

from drrl.envs.baxter.env import SUBSTEPS, BaxterReachEnv
from drrl.envs.baxter.model import neutral_pose
from drrl.envs.baxter.ros import POSITION_MODE, VELOCITY_MODE, RosBaxter
from drrl.envs.baxter.simulation import BaxterBatch

ARMS = ("right",)


class SimulatedBridge:
    """rosbridge's topics and the robot's clock, answered by drrl's simulation of one Baxter: Rethink's topics and
    messages in, the simulated robot's joint states and collision flags out, one control period per ``sleep``."""

    def __init__(self, arms: tuple[str, ...]):
        self.arms, self.sim, self.time = arms, BaxterBatch(1, arms, SUBSTEPS, threads=1), 0.0
        neutral = np.concatenate([neutral_pose(side) for side in arms])[None]
        self.sim.restart(np.arange(1), neutral, np.zeros((1, len(arms), 3)))
        self.subscribers: dict[str, list] = defaultdict(list)
        self.published: dict[str, list[dict]] = defaultdict(list)

    def topic(self, name: str, message_type: str) -> SimulatedBridge.Topic:
        return SimulatedBridge.Topic(self, name)

    class Topic:
        def __init__(self, bridge: SimulatedBridge, name: str):
            self.bridge, self.name = bridge, name

        def subscribe(self, callback) -> None:
            self.bridge.subscribers[self.name].append(callback)
            self.bridge.publish_state()

        def publish(self, message: dict) -> None:
            self.bridge.published[self.name].append(dict(message))

    def monotonic(self) -> float:
        return self.time

    def sleep(self, seconds: float) -> None:
        """One control period of the simulation under the latest command of each arm: velocities held, or a position
        reached at rest (the robot's own position controller, idealised)."""
        assert seconds == pytest.approx(self.sim.control_period)
        commands = [self.published[f"/robot/limb/{side}/joint_command"][-1] for side in self.arms]
        values = np.concatenate([c["command"] for c in commands])[None]
        if commands[0]["mode"] == POSITION_MODE:
            self.sim.restart(np.arange(1), values, self.sim.targets.copy())
        else:
            assert commands[0]["mode"] == VELOCITY_MODE
            self.sim.step(values)
        self.time += seconds
        self.publish_state()

    def publish_state(self) -> None:
        names = [f"{side}_{joint}" for side in self.arms for joint in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")]
        # in another order than drrl's, as a robot's joint_states may be
        position, velocity = self.sim.qpos[0, ::-1].tolist(), self.sim.qvel[0, ::-1].tolist()
        state = {"name": names[::-1], "position": position, "velocity": velocity}
        for callback in self.subscribers["/robot/joint_states"]:
            callback(state)
        for side in self.arms:
            for callback in self.subscribers[f"/robot/limb/{side}/collision_detection_state"]:
                callback({"collision_state": bool(self.sim.in_contact[0])})


def test_the_reach_task_on_rosbaxter_matches_the_simulated_env_step_for_step():
    bridge = SimulatedBridge(ARMS)
    real = BaxterReachEnv(robot=RosBaxter(ARMS, topic=bridge.topic, clock=bridge), arms=ARMS)
    simulated = BaxterReachEnv(arms=ARMS)
    assert bridge.published["/robot/set_super_enable"] == [{"data": True}]
    observation, _ = real.reset(seed=3)
    expected, _ = simulated.reset(seed=3)
    np.testing.assert_allclose(observation, expected, atol=1e-5)
    rng = np.random.default_rng(0)
    gain = rng.normal(0, 0.3, (7, 3))
    for _ in range(60):
        action = np.clip(gain @ observation[-3:], -1, 1)  # a feedback on the end-point offsets
        observation, reward, terminated, _, _ = real.step(action)
        expected, expected_reward, *_ = simulated.step(action)
        np.testing.assert_allclose(observation, expected, atol=1e-5)
        assert reward == expected_reward and not terminated
    commands = bridge.published["/robot/limb/right/joint_command"]
    assert commands[-1]["mode"] == VELOCITY_MODE and commands[-1]["names"][0] == "right_s0"
    assert bridge.time == pytest.approx(61 * 0.01)  # one control period a step (the reset: one to the start pose)


def test_an_episode_that_fails_stops_the_robot_where_it_is():
    bridge = SimulatedBridge(ARMS)
    env = BaxterReachEnv(robot=RosBaxter(ARMS, topic=bridge.topic, clock=bridge), arms=ARMS)
    env.reset(seed=0)
    action = np.zeros(7)
    action[5] = 4.0  # a wrist pitch driven into its limit
    for _ in range(200):
        *_, terminated, _, _ = env.step(action)
        if terminated:
            break
    assert terminated
    hold = bridge.published["/robot/limb/right/joint_command"][-1]
    assert hold["mode"] == POSITION_MODE
    np.testing.assert_allclose(hold["command"], env.robot.qpos[0])
    env.step(action)  # a stopped robot ignores commands: it holds
    assert bridge.published["/robot/limb/right/joint_command"][-1]["mode"] == POSITION_MODE


def test_the_simulation_stops_too():
    sim = BaxterBatch(2, ARMS, SUBSTEPS, threads=1)
    sim.restart(np.arange(2), np.tile(neutral_pose("right"), (2, 1)), np.zeros((2, 1, 3)))
    sim.stop(np.array([1]))
    for _ in range(20):
        sim.step(np.full((2, 7), 0.5))
    assert np.abs(sim.qvel[0]).min() > 0.4 and np.abs(sim.qvel[1]).max() < 1e-3


def test_a_robot_that_cannot_run_the_task_is_refused():
    bridge = SimulatedBridge(ARMS)
    robot = RosBaxter(ARMS, topic=bridge.topic, clock=bridge)
    with pytest.raises(ValueError, match="moving"):
        BaxterReachEnv(robot=robot)  # both arms asked, one moving
    slow = RosBaxter(ARMS, topic=bridge.topic, clock=bridge, control_period=0.02)
    with pytest.raises(ValueError, match=r"every 0\.01 s"):
        BaxterReachEnv(robot=slow, arms=ARMS)
    with pytest.raises(ValueError, match="only drrl's simulation renders"):
        env = BaxterReachEnv(robot=robot, arms=ARMS, render_mode="rgb_array")
        env.reset(seed=0)
        env.render()


def test_without_roslibpy_one_line_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "roslibpy", None)
    with pytest.raises(ImportError, match=r'pip install "drrl\[ros\]"'):
        RosBaxter(ARMS)


def test_a_step_after_a_pause_holds_its_command_for_a_whole_period():
    bridge = SimulatedBridge(ARMS)
    env = BaxterReachEnv(robot=RosBaxter(ARMS, topic=bridge.topic, clock=bridge), arms=ARMS)
    env.reset(seed=0)
    bridge.time += 1.0  # the caller paused, e.g. to measure
    paused = bridge.time
    env.step(np.zeros(7))  # the bridge asserts that it sleeps one control period, not the 0.01 s already past
    assert bridge.time == pytest.approx(paused + 0.01)
