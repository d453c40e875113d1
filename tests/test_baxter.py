"""Baxter (thesis 5.2) in MuJoCo: the model against independent kinematics, the actuators, the reach task (5.10) and
the Gymnasium interface."""

from __future__ import annotations

import itertools
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from drrl.envs.baxter.env import BaxterReachEnv, BaxterReachVectorEnv
from drrl.envs.baxter.kinematics import arm_points
from drrl.envs.baxter.model import ARM, SIDES, baxter_xml, import_mujoco, load_model, neutral_pose
from drrl.envs.baxter.simulation import BaxterBatch
from drrl.envs.baxter.standin import Actuation, StandIn
from drrl.envs.baxter.task import (
    LIMIT_MARGIN,
    TARGET_GAIN,
    TARGET_SPAN,
    WORKSPACE,
    ReachTask,
    reach_fraction,
    reach_verdict,
    side_box,
)
from drrl.envs.registry import lookup
from drrl.settings import TrainConfig

mujoco = import_mujoco()  # headless GL unless MUJOCO_GL says otherwise

LOW = np.array([joint.lower for joint in ARM])
HIGH = np.array([joint.upper for joint in ARM])
MAX_VELOCITY = np.array([joint.max_velocity for joint in ARM])

# ---------------------------------------------------------------------------------------------------- kinematics

# Standard Denavit–Hartenberg parameters of one arm, (a, d, α, θ offset), from ../shared/reference/baxter/README.md
DH = [
    (0.069, 0.27035, -np.pi / 2, 0.0),
    (0.0, 0.0, np.pi / 2, np.pi / 2),
    (0.069, 0.36442, -np.pi / 2, 0.0),
    (0.0, 0.0, np.pi / 2, 0.0),
    (0.010, 0.37429, -np.pi / 2, 0.0),
    (0.0, 0.0, np.pi / 2, 0.0),
    (0.0, 0.229525, 0.0, 0.0),
]


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def translation(x: float, y: float, z: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, 3] = x, y, z
    return transform


def dh_end_point(q: np.ndarray, side: str) -> np.ndarray:
    """The gripper end-point in the torso frame: arm mount (∓0.219645 m, ∓45°), the DH chain, 0.025 m beyond."""
    sign = -1.0 if side == "right" else 1.0
    pose = translation(0.024645, sign * 0.219645, 0.118588) @ rotation_z(sign * np.pi / 4)
    pose = pose @ translation(0.055695, 0.0, 0.011038)
    for angle, (a, d, alpha, offset) in zip(q, DH, strict=True):
        pose = pose @ rotation_z(angle + offset) @ translation(a, 0.0, d) @ rotation_x(alpha)
    return (pose @ np.array([0.0, 0.0, 0.025, 1.0]))[:3]


def test_end_points_match_the_denavit_hartenberg_table_within_a_millimetre():
    model = load_model(SIDES)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    for _ in range(100):
        q = rng.uniform(np.tile(LOW, 2), np.tile(HIGH, 2))
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for k, side in enumerate(SIDES):
            simulated = data.site(f"{side}_end_point").xpos
            np.testing.assert_allclose(simulated, dh_end_point(q[7 * k : 7 * k + 7], side), atol=1e-3, rtol=0)


def test_closed_form_kinematics_put_every_point_where_mujoco_does():
    model = load_model(SIDES)
    data = mujoco.MjData(model)
    q = np.random.default_rng(1).uniform(np.tile(LOW, 2), np.tile(HIGH, 2), (30, 14))
    for k, side in enumerate(SIDES):
        points = arm_points(q[:, 7 * k : 7 * k + 7], side)
        for row, angles in enumerate(q):
            data.qpos[:] = angles
            mujoco.mj_kinematics(model, data)
            bodies = [data.body(f"{side}_{name}").xpos for name in ("e1", "w1", "hand")]
            expected = np.stack([*bodies, data.site(f"{side}_end_point").xpos])
            np.testing.assert_allclose(points[row], expected, atol=1e-6, rtol=0)
        np.testing.assert_allclose(points[0, 3], dh_end_point(q[0, 7 * k : 7 * k + 7], side), atol=1e-3, rtol=0)


def test_model_has_the_urdf_limits_masses_and_actuators():
    model = load_model(("right",))
    np.testing.assert_allclose(model.jnt_range, np.stack([LOW, HIGH], axis=1))
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], MAX_VELOCITY)
    np.testing.assert_allclose(model.actuator_forcerange[:, 1], [50, 100, 50, 50, 15, 15, 15])
    arm_mass = sum(model.body(f"right_{joint.name}").mass[0] for joint in ARM) + model.body("right_hand").mass[0]
    assert arm_mass == pytest.approx(5.70044 + 3.22698 + 4.31272 + 2.07206 + 2.24665 + 1.60979 + 0.35093 + 0.19125)
    assert model.opt.timestep == 0.002 and model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert np.all(model.body_gravcomp[[model.body(f"right_{joint.name}").id for joint in ARM]] == 1)
    assert model.nq == 7 and mujoco.MjModel.from_xml_string(baxter_xml()).nq == 14


def inverse_kinematics(model, data, site: int, target: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Damped least squares on the end-point position, kept 0.05 rad inside the joint limits."""
    q, jacobian = start.copy(), np.zeros((3, model.nv))
    for _ in range(300):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        error = target - data.site_xpos[site]
        if np.linalg.norm(error) < 1e-4:
            break
        mujoco.mj_jacSite(model, data, jacobian, None, site)
        step = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + 1e-3 * np.eye(3), error)
        q = np.clip(q + 0.5 * step, model.jnt_range[:, 0] + 0.05, model.jnt_range[:, 1] - 0.05)
    return q


@pytest.mark.parametrize("side", SIDES)
def test_every_corner_of_the_workspace_is_reachable_without_touching_anything(side):
    model = load_model((side,))
    data = mujoco.MjData(model)
    site = model.site(f"{side}_end_point").id
    for corner in itertools.product(*np.stack(side_box(WORKSPACE, side)).T):
        q = inverse_kinematics(model, data, site, np.array(corner), neutral_pose(side))
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        assert np.linalg.norm(data.site_xpos[site] - corner) < 1e-3, corner
        assert data.ncon == 0, corner


# ---------------------------------------------------------------------------------------------------- actuators


def test_a_joint_velocity_command_is_tracked():
    """Each joint alone, commanded 0.5 rad/s from rest: after 0.5 s it moves at 0.5·50/50.7 (the joint damping of
    0.7 against kv = 50), and the other joints stay still."""
    sims = BaxterBatch(7, ("right",), substeps=5)
    sims.restart(np.arange(7), np.tile(neutral_pose("right"), (7, 1)), np.zeros((7, 1, 3)))
    command = 0.5 * np.eye(7)
    for _ in range(50):
        sims.step(command)
    np.testing.assert_allclose(np.diag(sims.qvel), 0.5 * 50 / 50.7, rtol=2e-3)
    assert np.abs(sims.qvel[~np.eye(7, dtype=bool)]).max() < 0.01


def test_a_batch_step_is_plain_mj_step_and_what_it_reads_belongs_to_the_new_state():
    """Stepping a control period a call, with the stages kept for the next call, gives the states of mj_step on one
    MjData, and the end-points read after each call are those of a fresh mj_forward at the new state."""
    sims = BaxterBatch(2, ("right",), substeps=5)
    sims.restart(np.arange(2), np.tile(neutral_pose("right"), (2, 1)), np.zeros((2, 1, 3)))
    data = mujoco.MjData(sims.model)
    data.qpos[:] = sims.qpos[1]
    commands = np.random.default_rng(0).uniform(-0.5, 0.5, (30, 7))
    site = sims.model.site("right_end_point").id
    for command in commands:
        sims.step(np.stack([np.zeros(7), command]))
        data.ctrl[:] = command
        mujoco.mj_step(sims.model, data, nstep=5)
        np.testing.assert_array_equal(sims.qpos[1], data.qpos)
        mujoco.mj_forward(sims.model, data)
        np.testing.assert_allclose(sims.end_points[1, 0], data.site_xpos[site], atol=1e-12)


def test_holding_still_stays_still():
    sims = BaxterBatch(1, SIDES, substeps=5)
    start = np.concatenate([neutral_pose(side) for side in SIDES])[None]
    sims.restart(np.arange(1), start, np.zeros((1, 2, 3)))
    for _ in range(200):
        sims.step(np.zeros((1, 14)))
    np.testing.assert_allclose(sims.qpos, start, atol=1e-6)


def test_joints_stop_at_their_limits():
    """Each joint alone, driven at full speed into each of its limits from 0.5 rad away, stops within 0.015 rad of
    it: sims 0–6 drive joint k up, sims 7–13 down."""
    sims = BaxterBatch(14, ("right",), substeps=5)
    starts = np.tile(neutral_pose("right"), (14, 1))
    joint, up = np.tile(np.arange(7), 2), np.arange(14) < 7
    limits = np.where(up, HIGH[joint], LOW[joint])
    starts[np.arange(14), joint] = limits - np.where(up, 0.5, -0.5)
    sims.restart(np.arange(14), starts, np.zeros((14, 1, 3)))
    commands = np.zeros((14, 7))
    commands[np.arange(14), joint] = np.where(up, 1.0, -1.0) * MAX_VELOCITY[joint]
    beyond = np.zeros(14)
    for _ in range(100):
        sims.step(commands)
        angles = sims.qpos[np.arange(14), joint]
        beyond = np.maximum(beyond, np.where(up, angles - limits, limits - angles))
    assert beyond.max() < 0.015
    np.testing.assert_allclose(sims.qpos[np.arange(14), joint], limits, atol=0.015)


def test_a_simulation_gone_bad_raises_instead_of_being_quietly_reset():
    sims = BaxterBatch(3, ("right",), substeps=5)
    sims.restart(np.arange(3), np.tile(neutral_pose("right"), (3, 1)), np.zeros((3, 1, 3)))
    sims.qpos[1, 2] = np.nan
    with pytest.raises(RuntimeError, match=r"mjWARN_BADQPOS\) in simulation\(s\) \[1\]"):
        sims.step(np.zeros((3, 7)))


# ---------------------------------------------------------------------------------------------------- the task


def test_thesis_reward_counts_steps_away_and_charges_failure_twice_the_remaining_steps():
    task = ReachTask(arms=SIDES, horizon=2000)
    distances = np.array([[0.05, 0.01], [0.051, 0.0], [0.3, 0.3], [0.0, 0.0]])
    failed = np.array([False, False, False, True])
    reward, terminated = task.rewards(distances, failed, np.array([1, 1, 1, 10]))
    assert reward.tolist() == [0.0, -1.0, -1.0, -2.0 * (2000 - 10)]
    assert terminated.tolist() == [False, False, False, True]
    dense, _ = ReachTask(arms=SIDES, reward="dense").rewards(distances, failed, np.array([1, 1, 1, 10]))
    np.testing.assert_allclose(dense, [-0.06, -0.051, -0.6, -3980.0])


def test_targets_outside_the_workspace_are_refused():
    with pytest.raises(ValueError, match="outside the right arm's reachable workspace"):
        ReachTask(arms=("right",), fixed_target=(1.5, -0.3, 0.1))
    with pytest.raises(ValueError, match="outside the left arm's reachable workspace"):
        ReachTask(arms=("left",), fixed_target=(0.7, 0.3, 0.1))  # given for the right arm: mirrored to y = -0.3
    with pytest.raises(ValueError, match="target_box corner"):
        ReachTask(targets="random", target_box=((0.5, -0.5, -0.5), (0.8, -0.2, 0.2)))  # reaches under the table
    with pytest.raises(ValueError, match="reward must be one of"):
        ReachTask(reward="shaped")
    with pytest.raises(ValueError, match="outside"):
        gym.make("drrl/BaxterReachRight-v0", fixed_target=(0.0, 0.0, 0.0))


def test_random_targets_fill_their_box_and_fixed_targets_are_mirrored():
    env = BaxterReachVectorEnv(200, arms=SIDES, targets="random")
    env.reset(seed=0)
    for k, side in enumerate(SIDES):
        low, high = side_box(((0.55, -0.55, -0.05), (0.80, -0.25, 0.20)), side)
        targets = env.robot.targets[:, k]
        assert np.all(targets >= low) and np.all(targets <= high)
        assert np.all(targets.max(axis=0) - targets.min(axis=0) > 0.9 * (high - low))
    fixed = BaxterReachVectorEnv(1, arms=SIDES)
    fixed.reset(seed=0)
    np.testing.assert_allclose(fixed.robot.targets[0], [[0.75, -0.40, 0.05], [0.75, 0.40, 0.05]])


def test_touching_the_table_fails_the_episode():
    env = BaxterReachVectorEnv(1, arms=("right",))
    env.reset(seed=0)
    over_the_table = neutral_pose("right")
    over_the_table[[0, 1, 3, 5]] = 0.6, 0.3, 0.0, 0.0  # arm stretched forward, just above the table top
    env.robot.restart(np.arange(1), over_the_table[None], env.robot.targets.copy())
    down = np.zeros((1, 7))
    down[0, 3] = 1.5  # bend the elbow: the forearm swings down onto the table
    for t in range(1, 100):  # noqa: B007 (t is read after the loop)
        _, reward, terminated, truncated, _ = env.step(down)
        if terminated[0]:
            break
    assert terminated[0] and not truncated[0] and 1 < t < 60
    assert reward[0] == -2.0 * (2000 - t)
    assert env.robot.in_contact[0] and not env.task.at_limit(env.robot.qpos)[0]


def test_the_closed_form_table_rule_fails_within_a_few_steps_of_the_real_contact():
    env = BaxterReachVectorEnv(1, arms=("right",))
    env.reset(seed=0)
    over_the_table = neutral_pose("right")
    over_the_table[[0, 1, 3, 5]] = 0.6, 0.3, 0.0, 0.0
    env.robot.restart(np.arange(1), over_the_table[None], env.robot.targets.copy())
    down = np.zeros((1, 7))
    down[0, 3] = 1.5
    closed_form = []
    for _ in range(100):
        observation, _, terminated, _, _ = env.step(down)
        closed_form.append(env.task.observed_reward(observation, np.ones(1))[1][0])
        if terminated[0]:
            break
    assert len(closed_form) > 10 and closed_form[-1]
    assert not any(closed_form[:-5])  # not long before the real contact either


def test_closed_form_reward_and_offsets_match_the_simulation_until_a_contact():
    env = BaxterReachVectorEnv(64, arms=SIDES)
    observation, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    weights = 0.3 * rng.standard_normal((observation.shape[1], 14))
    compared = 0
    for _ in range(300):
        actions = np.tanh(observation @ weights) * np.tile(MAX_VELOCITY, 2)
        before, previous = env.elapsed_steps.copy(), observation
        observation, reward, terminated, _, _ = env.step(actions)
        stepped = before + 1 == env.elapsed_steps  # not an autoreset
        np.testing.assert_allclose(
            env.task.complete_observation(previous, observation)[stepped], observation[stepped], atol=1e-5, rtol=0
        )
        closed_reward, closed_end = env.task.observed_reward(observation, env.elapsed_steps)
        real_contact = env.robot.in_contact & ~env.task.at_limit(env.robot.qpos)
        same = stepped & ~real_contact  # contacts with the body or the other arm need link shapes
        np.testing.assert_array_equal(closed_reward[same & ~closed_end], reward[same & ~closed_end])
        np.testing.assert_array_equal(closed_end[same & terminated], True)
        compared += int(same.sum())
    assert compared > 10_000


def test_the_tie_break_ranks_episodes_that_never_reach_by_their_distance():
    env = BaxterReachVectorEnv(2, arms=("right",))
    observation, info = env.reset(seed=0)
    steps = np.ones(2)
    plain, _ = env.task.observed_reward(observation, steps)
    broken, ended = env.task.observed_reward(observation, steps, tie_break=0.1)
    np.testing.assert_array_equal(plain, -1.0)  # neither start is at its target: 5.10 ties them
    np.testing.assert_allclose(broken, -1.0 - 0.1 * info["distance"], rtol=1e-6)
    assert not ended.any() and broken[np.argmin(info["distance"])] == broken.max()
    assert lookup("baxter-reach-right").reward(observation, steps)[0] == pytest.approx(broken)


def test_imagined_rewards_cost_the_joints_speeds_so_that_a_reach_ends_at_rest():
    env = BaxterReachVectorEnv(1, arms=("right",))
    observation, _ = env.reset(seed=0)
    turning = observation.copy()
    turning[:, 7:14] = [[0.5, 0, 0, 0, 0, 0, -0.25]]  # fractions of the joints' velocity limits
    steps = np.ones(1)
    still, _ = env.task.observed_reward(observation, steps, tie_break=0.1, stillness=0.1)
    moving, _ = env.task.observed_reward(turning, steps, tie_break=0.1, stillness=0.1)
    assert moving[0] == pytest.approx(still[0] - 0.1 * 0.75)
    assert lookup("baxter-reach-right").reward(turning, steps)[0] == pytest.approx(moving)


def test_running_into_a_joint_limit_fails_the_episode():
    env = BaxterReachVectorEnv(1, arms=("right",))
    env.reset(seed=0)
    toward_limit = np.zeros((1, 7))
    toward_limit[0, 6] = 4.0  # the wrist roll w2 turns freely until its stop at 3.059 rad
    for t in range(1, 200):  # noqa: B007 (t is read after the loop)
        _, reward, terminated, _, _ = env.step(toward_limit)
        if terminated[0]:
            break
    assert terminated[0] and 70 < t < 90  # ~3 rad at 4 rad/s
    assert env.task.at_limit(env.robot.qpos)[0] and reward[0] == -2.0 * (2000 - t)


def test_verdict_counts_episodes_that_held_the_target_for_half_the_horizon():
    returns = torch.tensor([[-100.0] * 19 + [-1001.0]])  # 19 episodes away 100 steps of 2000, one 1001 steps
    never_failed = torch.zeros(1, 20, dtype=torch.bool)
    assert reach_verdict(returns, never_failed) == {"held_95": True, "held_80": True, "no_failure": True}
    one_failed = never_failed.clone()
    one_failed[0, 0] = True
    assert reach_verdict(returns, one_failed) == {"held_95": False, "held_80": True, "no_failure": False}
    assert reach_fraction(torch.tensor([0.05, 0.06, 0.01, 0.0]), torch.tensor([False, False, False, True])) == 0.5


# ---------------------------------------------------------------------------------------------------- Gymnasium


@pytest.mark.parametrize(
    "env_id", ["drrl/BaxterReachRight-v0", "drrl/BaxterReachTargets-v0", "drrl/BaxterReachRightStandIn-v0"]
)
def test_check_env_passes(env_id):
    env = gym.make(env_id)
    assert isinstance(env.unwrapped, BaxterReachEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*symmetric and normalized")  # the Box is in rad/s, by design
        check_env(env.unwrapped, skip_render_check=True)  # rendering: test_render_draws_the_robot


# ---------------------------------------------------------------------------------------------------- controllers


def test_joint_target_commands_follow_the_proportional_law():
    task = ReachTask(arms=("right",), controller="joint_targets")
    low, high = np.array([j.lower for j in ARM]), np.array([j.upper for j in ARM])
    qpos = neutral_pose("right") + 0.1
    np.testing.assert_allclose(task.velocities(np.zeros((1, 7)), qpos[None]), [[-TARGET_GAIN * 0.1] * 7])
    actions = np.array([[1.0, -1.0, 0.5, 1.0, -0.2, 1.0, -1.0]])
    wanted = np.clip(neutral_pose("right") + TARGET_SPAN * actions[0], low + LIMIT_MARGIN, high - LIMIT_MARGIN)
    assert np.any(wanted != neutral_pose("right") + TARGET_SPAN * actions[0])  # some targets were held inside
    np.testing.assert_allclose(task.velocities(actions, qpos[None])[0], TARGET_GAIN * (wanted - qpos))
    velocity = ReachTask(arms=("right",))
    np.testing.assert_array_equal(velocity.velocities(actions, qpos[None]), actions)  # the thesis's actions


def test_a_zero_joint_target_action_holds_the_neutral_pose():
    env = BaxterReachVectorEnv(1, arms=SIDES, controller="joint_targets")
    assert env.single_action_space == gym.spaces.Box(-1.0, 1.0, (14,), np.float32)
    env.reset(seed=3)
    for _ in range(300):  # 3 s: fifteen time constants of the controller
        _, _, terminated, _, _ = env.step(np.zeros((1, 14)))
        assert not terminated[0]
    np.testing.assert_allclose(env.robot.qpos[0], env.task.neutral, atol=0.01)


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_joint_targets_keep_every_joint_off_its_limits(sign):
    """Each joint of the right arm sent alone to its most extreme target settles inside its limits, never at them;
    with velocity actions the same pushes reach the limits (test_running_into_a_joint_limit_fails_the_episode)."""
    env = BaxterReachVectorEnv(7, arms=("right",), controller="joint_targets")
    env.reset(seed=0)
    actions = sign * np.eye(7)  # env i moves joint i only
    ended = np.zeros(7, dtype=bool)
    for _ in range(400):
        _, _, terminated, _, _ = env.step(actions)
        assert not env.task.at_limit(env.robot.qpos).any()
        ended |= terminated  # the shoulder pitched far down meets the table: a contact, not a limit
    assert ended.sum() <= 1
    angles = env.robot.qpos[np.arange(7), np.arange(7)]
    low, high = env.task.joint_low[:7], env.task.joint_high[:7]
    inside = np.clip(env.task.neutral[:7] + sign * TARGET_SPAN, low + LIMIT_MARGIN, high - LIMIT_MARGIN)
    np.testing.assert_allclose(angles[~ended], inside[~ended], atol=0.02)


def test_make_vec_gives_the_native_batch_with_velocity_bounded_actions():
    env = gym.make_vec("drrl/BaxterReach-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert type(env) is BaxterReachVectorEnv
    assert env.single_observation_space.shape == (2 * 14 + 12,)
    np.testing.assert_allclose(env.single_action_space.high, np.tile(MAX_VELOCITY, 2))
    np.testing.assert_allclose(env.single_action_space.low, -np.tile(MAX_VELOCITY, 2))
    obs, info = env.reset(seed=0)
    assert obs.shape == (3, 40) and obs.dtype == np.float32 and info["distance"].shape == (3,)
    obs, _, _, _, info = env.step(np.zeros((3, 14)))
    offsets = obs[:, 34:].reshape(3, 2, 3) * 0.1  # observed in tenths of a metre
    np.testing.assert_allclose(info["distance"], np.linalg.norm(offsets, axis=2).max(axis=1), rtol=1e-5)
    one_arm = gym.make_vec("drrl/BaxterReachRight-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert one_arm.single_observation_space.shape == (20,) and one_arm.single_action_space.shape == (7,)


def test_seeded_reset_is_deterministic_and_per_env_seeds_do_not_depend_on_the_batch():
    env = BaxterReachVectorEnv(3, arms=("right",), targets="random")
    first, _ = env.reset(seed=[11, 22, 33])
    again, _ = env.reset(seed=[11, 22, 33])
    np.testing.assert_array_equal(first, again)
    alone, _ = BaxterReachVectorEnv(1, arms=("right",), targets="random").reset(seed=[22])
    np.testing.assert_array_equal(alone[0], first[1])
    assert not np.array_equal(first[0], first[1])
    start = first[:, :7] - neutral_pose("right")
    assert np.all(np.abs(start) <= 0.1) and np.all(first[:, 7:14] == 0.0)
    batch_seeded, _ = env.reset(seed=5)
    np.testing.assert_array_equal(batch_seeded, env.reset(seed=5)[0])


def test_single_env_matches_the_vector_env_seeded_alike_even_with_transition_noise():
    single = BaxterReachEnv(arms=("right",), action_noise=0.1)
    vector = BaxterReachVectorEnv(2, arms=("right",), action_noise=0.1)
    noiseless = BaxterReachVectorEnv(1, arms=("right",))
    obs_single, _ = single.reset(seed=4)
    obs_vector, _ = vector.reset(seed=[4, 4])
    obs_noiseless, _ = noiseless.reset(seed=[4])
    action = np.linspace(-1.0, 1.0, 7)
    for _ in range(20):
        np.testing.assert_array_equal(obs_single, obs_vector[0])
        np.testing.assert_array_equal(obs_vector[0], obs_vector[1])
        obs_single, reward, *_ = single.step(action)
        obs_vector, rewards, *_ = vector.step(np.stack([action, action]))
        obs_noiseless, *_ = noiseless.step(action[None])
        assert reward == rewards[0]
    assert np.abs(obs_noiseless[0, :7] - obs_single[:7]).max() > 1e-3  # the noise moved the joints


def test_next_step_autoreset_restarts_an_ended_env_and_ignores_its_action():
    env = BaxterReachVectorEnv(2, arms=("right",), horizon=3)
    env.reset(seed=[1, 2])
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(np.zeros((2, 7)))
    assert truncated.all() and not terminated.any()
    obs, reward, terminated, truncated, _ = env.step(np.full((2, 7), 1.0))
    restarted, _ = BaxterReachVectorEnv(2, arms=("right",), horizon=3).reset(seed=[1, 2])
    assert reward.tolist() == [0.0, 0.0] and not (terminated | truncated).any()
    assert env.elapsed_steps.tolist() == [0, 0]
    assert not np.array_equal(obs, restarted)  # the second start of each env's generator, not the first
    np.testing.assert_array_equal(obs[:, 7:14], 0.0)


def test_bad_actions_raise():
    env = BaxterReachVectorEnv(2, arms=("right",))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 7\)"):
        env.step(np.zeros((2, 14)))
    actions = np.zeros((2, 7))
    actions[1, 3] = np.nan
    with pytest.raises(ValueError, match=r"non-finite actions for envs \[1\]"):
        env.step(actions)
    single = BaxterReachEnv(arms=("right",))
    single.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        single.step(np.zeros((1, 7)))
    with pytest.raises(ValueError, match="non-finite"):
        single.step(np.full(7, np.inf))


def test_actions_beyond_the_velocity_limits_are_clipped_to_them():
    env = BaxterReachVectorEnv(2, arms=("right",))
    env.reset(seed=[3, 3])
    obs, *_ = env.step(np.stack([MAX_VELOCITY, 10 * MAX_VELOCITY]))
    np.testing.assert_array_equal(obs[0], obs[1])


def test_render_draws_the_robot_and_follows_it():
    env = gym.make("drrl/BaxterReachRight-v0", render_mode="rgb_array")
    env.reset(seed=0)
    try:
        before = env.render()
    except RuntimeError as error:
        pytest.skip(f"no headless OpenGL here: {error}")
    assert before.shape == (240, 320, 3) and before.dtype == np.uint8
    assert before.std() > 10  # not a blank picture
    for _ in range(30):
        env.step(np.array([1.5, 0, 0, 0, 0, 0, 0]))  # swing the shoulder
    assert np.abs(env.render().astype(int) - before).sum(axis=2).astype(bool).mean() > 0.005
    env.close()


def test_record_episode_writes_a_gif_of_the_policy(tmp_path):
    from PIL import Image

    from drrl.policies import linear
    from drrl.video import record_episode, write_video

    policy = linear(20, 7)
    center = torch.zeros(policy.num_params)
    center[-7] = 1.0  # bias of the s0 output: the shoulder turns at full speed
    env = gym.make("drrl/BaxterReachRight-v0", render_mode="rgb_array")
    try:
        recording = record_episode(policy, center, env, max_steps=12)
    except RuntimeError as error:
        pytest.skip(f"no headless OpenGL here: {error}")
    finally:
        env.close()
    assert recording.steps == 12 and recording.episode_return == -12.0 and recording.fps == 25
    assert len(recording.frames) == 4  # the start, then every 4th control step: 25 frames per second of 100
    assert np.abs(recording.frames[-1].astype(int) - recording.frames[0]).sum() > 0  # the arm moved
    write_video(recording.frames, tmp_path / "reach.gif", recording.fps)
    with Image.open(tmp_path / "reach.gif") as gif:
        assert gif.n_frames == 4 and gif.size == (320, 240)
    with pytest.raises(ValueError, match="unsupported video format"):
        write_video(recording.frames, tmp_path / "reach.avi", fps=25)


@pytest.mark.slow
def test_drrl_train_and_render_a_baxter_run_end_to_end(tmp_path):
    """`drrl train baxter-reach-right` writes the held verdict into metrics.csv; `drrl render` records the run."""
    from click.testing import CliRunner

    from drrl.cli import main

    (tmp_path / "tiny.toml").write_text("popsize = 2\nbudget = 2\nmax_steps = 10\neval_episodes = 1\n")
    run = tmp_path / "run"
    trained = CliRunner().invoke(
        main,
        [
            "train",
            "baxter-reach-right",
            "--model-free",
            "--config",
            str(tmp_path / "tiny.toml"),
            "--out",
            str(run),
            "--quiet",
        ],
    )
    assert trained.exit_code == 0, trained.output
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"held_95", "held_80", "no_failure"} <= set(header)
    judged = CliRunner().invoke(main, ["eval", str(run), "--episodes", "2"])
    assert (
        judged.exit_code == 0
        and "no-failure:   yes" in judged.output
        and "2/2 episodes without a failure" in judged.output
    ), judged.output
    transferred = CliRunner().invoke(main, ["eval", str(run), "--episodes", "2", "--env", "baxter-reach-right-standin"])
    assert transferred.exit_code == 0 and transferred.output.startswith("drrl/BaxterReachRightStandIn-v0, ")
    elsewhere = CliRunner().invoke(main, ["eval", str(run), "--env", "baxter-reach"])
    assert elsewhere.exit_code == 1 and "trained on drrl/BaxterReachRight-v0, whose observation" in elsewhere.output
    rendered = CliRunner().invoke(main, ["render", str(run), "--out", str(tmp_path / "reach.gif"), "--max-steps", "8"])
    if rendered.exit_code != 0 and "headless rendering failed" in rendered.output:
        pytest.skip(rendered.output)
    assert rendered.exit_code == 0, rendered.output
    assert "wrote" in rendered.output and "final end-point distance" in rendered.output
    assert (tmp_path / "reach.gif").stat().st_size > 1000
    standin = ["render", str(run), "--out", str(tmp_path / "standin.gif"), "--max-steps", "8"]
    on_standin = CliRunner().invoke(main, [*standin, "--env", "baxter-reach-right-standin"])
    assert on_standin.exit_code == 0 and (tmp_path / "standin.gif").stat().st_size > 1000, on_standin.output
    mismatch = CliRunner().invoke(main, [*standin, "--env", "baxter-reach"])
    assert mismatch.exit_code == 1 and "trained on drrl/BaxterReachRight-v0, whose observation" in mismatch.output
    refused = CliRunner().invoke(main, ["render", str(run), "--out", str(tmp_path / "reach.avi")])
    assert refused.exit_code != 0 and "unsupported video format '.avi'" in refused.output


def test_headless_gl_prefers_egl_then_osmesa_and_else_leaves_rendering_off(monkeypatch):
    import ctypes.util

    from drrl.envs.baxter.model import headless_gl

    def finder(found):
        return lambda name: f"lib{name}.so" if name in found else None

    for found, backend in ((("EGL", "OSMesa"), "egl"), (("OSMesa",), "osmesa"), ((), "disable")):
        monkeypatch.setattr(ctypes.util, "find_library", finder(found))
        assert headless_gl() == backend


# ---------------------------------------------------------------------------------------------------- training


def test_short_training_runs_and_counts_every_step():
    """Four candidates near the zero policy (σ = 0.001) hold still for max_steps = 25 steps: nothing fails, so
    every episode lasts exactly 25 steps."""
    from drrl.training.loop import run
    from drrl.training.train import prepare

    config = TrainConfig(
        env="drrl/BaxterReachRight-v0", popsize=4, budget=8, sigma_init=0.001, max_steps=25, eval_episodes=2
    )
    counters = run(prepare(config))
    assert counters.iteration == 2 and counters.real_episodes == 8
    assert counters.real_steps == 8 * 25
    assert counters.rows[-1]["center_return"] == -25.0  # 25 steps away from the target


# ---------------------------------------------------------------------------------------------------- stand-in


def test_a_stand_in_robot_has_its_own_fixed_masses_and_damping_and_nominal_gravity_compensation():
    nominal = load_model(("right",))
    robot, again = (StandIn(seed=4).model(nominal, ("right",)) for _ in range(2))
    links = [nominal.body(f"right_{joint.name}").id for joint in ARM]
    scale = robot.body_mass[links] / nominal.body_mass[links]
    assert np.all((scale >= 0.8) & (scale <= 1.2)) and np.ptp(scale) > 0.05
    np.testing.assert_allclose(robot.body_gravcomp[links] * robot.body_mass[links], nominal.body_mass[links])
    damping = robot.dof_damping[:7] / nominal.dof_damping[:7]
    assert np.all((damping >= 0.8) & (damping <= 1.2)) and np.ptp(damping) > 0.05
    np.testing.assert_array_equal(again.body_mass, robot.body_mass)  # one robot per seed
    assert not np.array_equal(StandIn(seed=5).model(nominal, ("right",)).body_mass, robot.body_mass)
    assert nominal.body_mass[links[0]] == ARM[0].mass  # the cached nominal model is untouched


def test_a_stand_in_acts_a_period_late_with_a_lag_and_reads_noisy_sensors():
    exact = StandIn(mass_error=0, damping_error=0, lag=0, angle_noise=0, velocity_noise=0)
    late = BaxterReachVectorEnv(1, arms=("right",), stand_in=exact)
    now = BaxterReachVectorEnv(1, arms=("right",))
    for env in (late, now):
        env.reset(seed=[3])
    push = np.full((1, 7), 0.5)
    late.step(push)
    now.step(push)
    assert np.abs(late.robot.qvel).max() < 0.01 < np.abs(now.robot.qvel).max()  # the command has not arrived yet
    late.step(np.zeros((1, 7)))
    assert np.abs(late.robot.qvel).max() > 0.1  # it arrives one period late
    actuation = Actuation(StandIn(delay=0, lag=0.05), 1, 1, 0.01)
    followed = [actuation(np.ones((1, 1)))[0, 0] for _ in range(5)]
    np.testing.assert_allclose(followed, 1 - np.exp(-0.01 * np.arange(1, 6) / 0.05))  # first-order lag
    noisy = BaxterReachVectorEnv(2, arms=("right",), stand_in={"angle_noise": 0.01})
    observation, _ = noisy.reset(seed=[1, 2])
    error = observation[:, :7] - noisy.robot.qpos
    assert 0.001 < np.abs(error).max() < 0.05  # readings off by about 0.01 rad; the state itself is not
