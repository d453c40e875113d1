"""Baxter's grippers, the blocks and the stacking tasks (thesis 5.2's wood stacking)."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import drrl.envs  # noqa: F401  (registers the envs)
from drrl.envs.baxter.grasping import (
    BLOCK_SIZE,
    CLOSED_WIDTH,
    FINGER_TRAVEL,
    GRIP_FORCE,
    OPEN_WIDTH,
    PAD_THICKNESS,
    load_grasping_model,
)
from drrl.envs.baxter.model import TABLE_TOP, import_mujoco, neutral_pose
from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.stack_env import BaxterStackEnv, BaxterStackVectorEnv, demonstrations
from drrl.envs.baxter.stacking import (
    BLOCK_TOP_REST,
    HORIZON,
    SETTLE_STEPS,
    StackTask,
    fingertip_heights,
    stacked_fraction,
)

mujoco = import_mujoco()


def test_the_gripper_has_rethinks_travel_and_force_and_the_blocks_are_pine():
    model = load_grasping_model(("right",), 2)
    for finger in (1, 2):
        np.testing.assert_allclose(model.joint(f"right_finger{finger}").range, [0.0, 0.020833])
    np.testing.assert_allclose(model.actuator("right_grip").forcerange, [-2 * GRIP_FORCE, 2 * GRIP_FORCE])
    assert GRIP_FORCE == 20.0 and FINGER_TRAVEL == 0.020833
    np.testing.assert_allclose(model.body("block0").mass, 0.04**3 * 500.0)  # 4 cm of pine at 500 kg/m³: 32 g
    data = mujoco.MjData(model)
    for closing, width in ((0.0, OPEN_WIDTH), (FINGER_TRAVEL, CLOSED_WIDTH)):
        data.qpos[7:9] = closing
        mujoco.mj_kinematics(model, data)
        pads = data.geom_xpos[[model.geom("right_finger1").id, model.geom("right_finger2").id]]
        np.testing.assert_allclose(np.linalg.norm(pads[0] - pads[1]) - PAD_THICKNESS, width, atol=1e-9)
    assert CLOSED_WIDTH < BLOCK_SIZE < OPEN_WIDTH


def _hold_block_in_open_fingers(model, data):
    """The right arm at its neutral pose, block 0 between the fingers, the fingers just touching it."""
    data.qpos[:7] = neutral_pose("right")
    mujoco.mj_forward(model, data)
    site = model.site("right_grip").id
    quaternion = np.zeros(4)
    mujoco.mju_mat2Quat(quaternion, data.site_xmat[site])
    start = model.jnt_qposadr[model.joint("block0").id]
    data.qpos[start : start + 7] = np.r_[data.site_xpos[site], quaternion]
    data.qpos[7:9] = (OPEN_WIDTH - BLOCK_SIZE) / 2 - 0.0005
    data.ctrl[7] = 0.0  # close
    mujoco.mj_forward(model, data)
    return site


def _command_grip_point(model, data, site, velocity):
    jacobian = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacobian, None, site)
    data.ctrl[:7] = np.linalg.lstsq(jacobian[:, :7], velocity, rcond=None)[0]


def test_a_grasped_block_lifted_10_cm_stays_in_the_fingers_for_5_s_without_jitter():
    model = load_grasping_model(("right",), 1)
    data = mujoco.MjData(model)
    site = _hold_block_in_open_fingers(model, data)
    block = model.body("block0").id

    def in_fingers():  # the block's centre in the gripper's frame
        return data.site_xmat[site].reshape(3, 3).T @ (data.xpos[block] - data.site_xpos[site])

    for _ in range(500):  # 1 s to grip
        _command_grip_point(model, data, site, np.zeros(3))
        mujoco.mj_step(model, data)
    held, height = in_fingers(), data.xpos[block, 2]
    for _ in range(1500):  # up 10 cm at 0.1 m/s
        if data.xpos[block, 2] - height >= 0.1:
            break
        _command_grip_point(model, data, site, np.array([0.0, 0.0, 0.1]))
        mujoco.mj_step(model, data)
    assert data.xpos[block, 2] - height >= 0.1
    offsets = []
    for _ in range(2500):  # held for 5 s
        _command_grip_point(model, data, site, np.zeros(3))
        mujoco.mj_step(model, data)
        offsets.append(in_fingers())
    drift = np.linalg.norm(np.array(offsets) - held, axis=1)
    assert drift.max() < 0.005
    speeds = np.linalg.norm(np.diff(offsets, axis=0), axis=1) / model.opt.timestep
    assert np.sqrt(np.mean(speeds[250:] ** 2)) < 0.001  # m/s relative to the fingers: no jitter
    touching = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, f"right_finger{k}_block0") for k in (1, 2)]
    assert all(data.sensordata[model.sensor_adr[s]] > 0 for s in touching)
    forces = []
    for k in range(data.ncon):
        contact = data.contact[k]
        if {contact.geom1, contact.geom2} == {model.geom("right_finger1").id, model.geom("block0").id}:
            wrench = np.zeros(6)
            mujoco.mj_contactForce(model, data, k, wrench)
            forces.append(wrench[0])
    assert 5.0 < sum(forces) <= GRIP_FORCE + 0.5  # the finger squeezes, within the gripper's force


@pytest.mark.parametrize(
    "options",
    [{}, {"blocks": 3, "positions": "random", "reward": "dense", "controller": "end_point"}],
)
def test_the_stacking_envs_pass_gymnasiums_checker(options):
    env = BaxterStackEnv(**options)
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (StackTask(**options).observation_size,)


def test_the_batch_and_the_single_env_give_the_same_episode():
    vector = gym.make_vec("drrl/BaxterStackRandom-v0", num_envs=3)
    single = gym.make("drrl/BaxterStackRandom-v0")
    observations, _ = vector.reset(seed=[5, 6, 7])
    observation, _ = single.reset(seed=6)
    np.testing.assert_array_equal(observations[1], observation)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (20, 3, 8))
    for action in actions:
        observations, rewards, _, _, _ = vector.step(action)
        observation, reward, _, _, _ = single.step(action[1])
        np.testing.assert_allclose(observations[1], observation, atol=1e-6)
        assert rewards[1] == reward


def _pick_and_place(env: BaxterStackVectorEnv, steps: int = HORIZON):
    """The scripted stacker's episodes: each env's return, the step its stack stood and whether it failed."""
    n = env.num_envs
    observations, _ = env.reset(seed=list(range(n)))
    stacker = ScriptedStacker(env.task)
    returns, stacked_at, failed = np.zeros(n), np.full(n, -1), np.zeros(n, bool)
    for t in range(steps):
        observations, reward, terminated, _, info = env.step(stacker.act(observations))
        active = (stacked_at < 0) & ~failed
        returns += np.where(active, reward, 0.0)
        stacked_at = np.where(info["stacked"] & active, t + 1, stacked_at)
        failed |= terminated & ~info["stacked"] & active
        if not ((stacked_at < 0) & ~failed).any():
            break
    return returns, stacked_at, failed


@pytest.mark.parametrize("options", [{"blocks": 2}, {"blocks": 3, "positions": "random"}])
def test_a_scripted_pick_and_place_builds_stacks_that_stand(options):
    env = BaxterStackVectorEnv(4, controller="end_point", **options)
    returns, stacked_at, failed = _pick_and_place(env)
    assert not failed.any() and (stacked_at > 0).all()
    # thesis reward: −1 a step without a standing stack, 0 for (at least) the second it stood, then the episode ends
    assert (returns == np.round(returns)).all() and (returns >= -(stacked_at - SETTLE_STEPS)).all()
    assert (returns <= -(stacked_at - SETTLE_STEPS) + 10).all()  # it stood only at the end, give or take a release
    terminated = torch.ones(4, dtype=torch.bool)
    assert stacked_fraction(torch.as_tensor(returns), terminated) == 1.0


def test_starts_from_demonstrations_are_states_of_the_scripted_stackers_episodes():
    states, lengths = demonstrations(("right",), 2, "fixed")
    assert (lengths > SETTLE_STEPS).all() and states.shape[:2] == (16, lengths.max())
    env = BaxterStackVectorEnv(32, demo_start=1.0)
    env.reset(seed=3)
    recorded = states[:, :, None]  # (episodes, steps, 1, state)
    now = env.robot.states()  # (envs, state)
    matches = np.abs(recorded[..., : now.shape[1]] - now).max(axis=-1) < 1e-9  # (episodes, steps, envs)
    assert matches.any(axis=(0, 1)).all()  # every start is some demonstration's state
    steps = np.nonzero(matches)[1]
    assert steps.max() > lengths.min() / 2  # and not only their first ones
    late = BaxterStackVectorEnv(32, demo_start=0.01)
    late.reset(seed=3)
    assert (late.robot.openings > 0.99).all()  # within their first 1 %: the gripper still open


@pytest.mark.parametrize(
    ("velocities", "into"),
    [([0.5, 0.5, 0, 0, 0, 0, 0], "the table"), ([0, 0.5, 0, -0.5, 0, 0, 0], "the elbow's limit")],
)
def test_joint_velocities_into_the_table_or_a_limit_fail_at_twice_the_remaining_steps(velocities, into):
    env = BaxterStackVectorEnv(1)  # the thesis's joint-velocity actions
    env.reset(seed=0)
    for _ in range(400):
        _, reward, terminated, _, info = env.step(np.array([[*velocities, 1.0]]))
        if terminated[0]:
            break
    assert terminated[0] and not info["stacked"][0]
    assert env.robot.in_contact[0] == (into == "the table")
    assert reward[0] == -2.0 * (HORIZON - env.elapsed_steps[0])


def test_the_end_point_controller_keeps_random_actions_from_failing():
    env = BaxterStackVectorEnv(32, controller="end_point")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (12, 32, 4)) * [0.5, 0.5, 0.5, 1.0]
    for action in actions:  # each held for 0.5 s: the grip points wander at up to 0.87 m/s
        for _ in range(50):
            _, _, terminated, _, _ = env.step(action)
            assert not terminated.any()
    assert (env.robot.grip_points[:, 0, 2] > BLOCK_TOP_REST).all()
    down = np.broadcast_to(env.task.gripper_frame(), (2, 3, 3))
    heights = fingertip_heights(np.array([[0.7, -0.4, TABLE_TOP + 0.03], [0.7, -0.4, 0.0]]), down)
    np.testing.assert_allclose(heights, [0.01, -TABLE_TOP - 0.02])  # pointing down: the pads end 2 cm below


def test_the_stack_rule_and_the_staged_progress():
    task = StackTask(reward="dense")
    lower = np.array([0.7, -0.35, BLOCK_TOP_REST])
    blocks = np.zeros((5, 2, 7))
    blocks[:, 0, :3] = lower
    blocks[:, 1, :3] = lower + np.array([0, 0, BLOCK_SIZE])
    blocks[1, 1, 0] += 0.025  # too far sideways
    blocks[2, 1, 2] += 0.01  # hovering
    blocks[3, 1, :3] = [0.65, -0.55, BLOCK_TOP_REST]  # still on the table
    touching = np.zeros((5, 1, 2, 2), dtype=bool)
    touching[4, 0, :, 1] = True  # still held
    speeds = np.zeros((5, 2))
    np.testing.assert_array_equal(task.placed(blocks[..., :3])[:, 0], [True, False, False, False, True])
    np.testing.assert_array_equal(task.standing(blocks, touching, speeds), [True, False, False, False, False])
    moving = speeds.copy()
    moving[0, 1] = 0.05
    assert not task.standing(blocks, touching, moving)[0]
    grips = np.zeros((5, 1, 3))
    grips[3, 0] = blocks[3, 1, :3]  # the gripper at the loose block
    progress = task.progress(blocks, touching, grips)
    assert progress[0] == 1.0 and progress[4] == 1.0
    assert 0.3 - 1e-9 <= progress[3] < 0.5  # near it: the reach stage whole, nothing held
    reward = task.rewards(np.array([True, False]), progress[[0, 3]], np.zeros(2, dtype=bool), np.array([5, 5]))
    np.testing.assert_allclose(reward, [0.0, progress[3] - 1.0])


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"blocks": 4}, "blocks must be 2 or 3"),
        ({"arms": ("right", "left")}, "stacking moves one arm"),
        ({"positions": "anywhere"}, "positions must be one of"),
        ({"controller": "torque"}, "controller must be one of"),
        ({"demo_start": 1.5}, "demo_start must be in"),
    ],
)
def test_bad_stacking_options_are_refused_in_one_line(options, message):
    with pytest.raises(ValueError, match=message):
        StackTask(**options)


def test_the_scripted_stacker_needs_end_point_actions():
    with pytest.raises(ValueError, match="end-point actions"):
        ScriptedStacker(StackTask())
