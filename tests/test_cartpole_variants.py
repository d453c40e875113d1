"""The partially observed and swing-up cart-poles: what they observe, start from and pay, and their Gymnasium face."""

from __future__ import annotations

import functools
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from test_cartpole import PHYSICS, C, discrete_lqr_gain, rk4_discretisation, upright_linearisation

import drrl  # noqa: F401  (registers the environments)
from drrl.envs.batch import make_batch_env
from drrl.envs.cartpole import (
    BalanceTask,
    CartPoleEnv,
    CartPoleVectorEnv,
    PartiallyObservedTask,
    SwingUpTask,
    balance_verdict,
    swing_up_verdict,
)
from drrl.envs.registry import lookup

VARIANTS = [
    ("drrl/CartPolePO-v0", "cartpole-po", PartiallyObservedTask),
    ("drrl/CartPoleSwingUp-v0", "cartpole-swingup", SwingUpTask),
]


# ---------------------------------------------------------------------------------------------------- Gymnasium


@pytest.mark.parametrize("env_id, alias, task", VARIANTS)
def test_check_env_passes_without_warnings(env_id, alias, task):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    assert isinstance(env.unwrapped, CartPoleEnv) and type(env.unwrapped.task) is task


@pytest.mark.parametrize("env_id, alias, task", VARIANTS)
def test_make_vec_and_the_alias_give_the_native_vector_env(env_id, alias, task):
    for env in (gym.make_vec(env_id, num_envs=6), make_batch_env(alias, 6)):
        assert type(env) is CartPoleVectorEnv and type(env.task) is task
        assert env.observation_space.shape == (6, task.observation_size) and env.action_space.shape == (6, 1)
        obs, _ = env.reset(seed=0)
        obs, reward, _terminated, _truncated, _ = env.step(np.zeros((6, 1), dtype=np.float32))
        assert obs.dtype == np.float32 and obs in env.observation_space and reward.shape == (6,)


def test_the_balance_task_keeps_its_registration_and_verdicts_are_registered():
    assert type(gym.make_vec("drrl/CartPole-v0", num_envs=2).task) is BalanceTask
    assert lookup("drrl/CartPolePO-v0").verdict is balance_verdict
    assert lookup("drrl/CartPoleSwingUp-v0").verdict is swing_up_verdict


# -------------------------------------------------------------------------------------------------- partially observed


def test_partially_observed_sees_position_and_angle_of_the_same_trajectory():
    full, partial = CartPoleVectorEnv(20), CartPoleVectorEnv(20, task=PartiallyObservedTask())
    obs_full, _ = full.reset(seed=list(range(20)))
    obs_partial, _ = partial.reset(seed=list(range(20)))
    actions = np.random.default_rng(0).uniform(-1, 1, (60, 20, 1))
    for action in actions:
        assert obs_partial.shape == (20, 2)
        np.testing.assert_array_equal(obs_partial, obs_full[:, [0, 2]])
        obs_full, *full_rest, _ = full.step(action)
        obs_partial, *partial_rest, _ = partial.step(action)
        for a, b in zip(full_rest, partial_rest, strict=True):  # reward, terminated, truncated
            np.testing.assert_array_equal(a, b)
    assert partial.task.horizon == 200


def test_balanced_alone_does_not_need_the_velocities():
    """The static feedback a = 0.25·θ balances every start for 200 steps, swinging undamped, far from the centre:
    "balanced" is within a feed-forward policy's reach on the partially observed task; "near-optimal" is not."""
    env = CartPoleVectorEnv(50, task=PartiallyObservedTask())
    obs, _ = env.reset(seed=2015)
    returns, failed = np.zeros(50), np.zeros(50, dtype=bool)
    for _ in range(200):
        obs, reward, terminated, _, _ = env.step(np.clip(0.25 * obs[:, 1:2], -1, 1))
        returns += reward
        failed |= terminated
    verdict = balance_verdict(torch.as_tensor(returns), torch.as_tensor(failed))
    assert verdict == {"balanced": True, "near_optimal": False}


# ---------------------------------------------------------------------------------------------------- swing-up


def wrapped(theta: np.ndarray) -> np.ndarray:
    """θ in (−π, π]: 0 upright."""
    return (theta + np.pi) % (2 * np.pi) - np.pi


def test_swing_up_starts_hanging_down_and_observes_the_angle_by_sine_and_cosine():
    env = CartPoleVectorEnv(500, task=SwingUpTask())
    obs, _ = env.reset(seed=3)
    state = env.state
    assert np.all(np.abs(state[:, 2] - np.pi) <= 0.2) and np.all(np.abs(state[:, 0]) <= 0.2)
    assert np.abs(state[:, 2] - np.pi).max() > 0.18 and np.all(state[:, 1::2] == 0.0)
    expected = np.stack([state[:, 0], state[:, 1], np.sin(state[:, 2]), np.cos(state[:, 2]), state[:, 3]], 1)
    np.testing.assert_allclose(obs, expected, rtol=1e-6)
    assert np.all(obs[:, 3] <= -np.cos(0.2) + 1e-6)


@pytest.mark.parametrize(
    ("s", "theta", "step", "reward", "terminated"),
    [
        (0.0, 0.0, 1, 1.0, False),  # upright at the centre
        (0.0, np.pi, 1, 0.0, False),  # hanging at the centre
        (0.0, 2 * np.pi, 9, 1.0, False),  # upright after one turn
        (0.0, np.pi / 2, 9, 0.5, False),
        (2.4, 0.0, 9, 0.75, False),  # the track end is inclusive and costs 0.25
        (-1.2, np.pi, 9, -0.0625, False),
        (2.41, 0.0, 10, -240.0, True),  # −(250 − 10)
        (-2.5, np.pi, 250, 0.0, True),
    ],
)
def test_swing_up_reward_cases(s, theta, step, reward, terminated):
    state = np.array([[s, 5.0, theta, -5.0]])  # velocities play no part
    got_reward, got_terminated = SwingUpTask().reward(state, step)
    assert got_reward[0] == pytest.approx(reward, abs=1e-12)
    assert got_terminated.tolist() == [terminated]


def test_swing_up_truncates_at_250_and_hanging_still_earns_nothing():
    env = CartPoleVectorEnv(3, task=SwingUpTask())
    env.reset(seed=0)
    env.state[:] = [0.0, 0.0, np.pi, 0.0]  # an equilibrium: the state stays exactly there
    for t in range(1, 251):
        _, reward, terminated, truncated, _ = env.step(np.zeros((3, 1)))
        assert reward == pytest.approx(0.0, abs=1e-12) and not terminated.any()
        assert truncated.tolist() == [t == 250] * 3


@functools.cache
def upright_lqr_gain() -> np.ndarray:
    """The reference LQR of the balance task (Q = diag(1000, 1, 1000, 1), R = 0.1; see test_cartpole.py)."""
    return discrete_lqr_gain(
        *rk4_discretisation(*upright_linearisation(), C.dt), np.diag([1000.0, 1, 1000, 1]), np.array([[0.1]])
    )


def energy_and_lqr(state: np.ndarray, catch: float = 0.5) -> np.ndarray:
    """A hand-made swing-up: pump the pole's energy towards the upright's (Åström & Furuta 2000) with the cart near
    the centre, and hand over to LQR at the upright once |θ| < ``catch``; catch = 0 never hands over."""
    m, l, g, total = C.pole_mass, C.half_length, C.gravity, C.cart_mass + C.pole_mass  # noqa: E741 (the thesis's l)
    s, s_dot, theta, theta_dot = state.T
    energy = 0.5 * (4 / 3) * m * l**2 * theta_dot**2 + m * g * l * (np.cos(theta) - 1)  # 0 at rest upright
    acceleration = np.clip(20 * energy * theta_dot * np.cos(theta), -10, 10) - s - 3 * s_dot
    upright = np.stack([s, s_dot, wrapped(theta), theta_dot], 1)
    force = np.where(np.abs(wrapped(theta)) < catch, -(upright @ upright_lqr_gain().T)[:, 0], total * acceleration)
    return np.clip(force / C.max_force, -1, 1)[:, None]


def swing_up_verdict_of(controller) -> tuple[dict[str, bool], np.ndarray]:
    env = CartPoleVectorEnv(50, task=SwingUpTask())
    env.reset(seed=2015)
    returns, failed = np.zeros(50), np.zeros(50, dtype=bool)
    for _ in range(250):
        _, reward, terminated, _, _ = env.step(controller(env.state))
        returns += np.where(failed, 0.0, reward)
        failed |= terminated
    return swing_up_verdict(torch.as_tensor(returns), torch.as_tensor(failed)), returns


def test_swing_up_is_solvable_and_solved_asks_for_the_pole_held_up():
    solved, returns = swing_up_verdict_of(energy_and_lqr)
    assert solved == {"solved": True} and returns.min() > 175
    circling, returns = swing_up_verdict_of(lambda state: energy_and_lqr(state, catch=0.0))  # up, never caught
    assert circling == {"solved": False} and 100 < returns.mean() < 160
    hanging, returns = swing_up_verdict_of(lambda state: np.zeros((len(state), 1)))
    assert hanging == {"solved": False} and abs(returns.mean()) < 5


@pytest.mark.parametrize(
    "env_id, task",
    [("drrl/CartPole-v0", BalanceTask()), *((env_id, task()) for env_id, _, task in VARIANTS)],
)
def test_each_cartpoles_declared_mirror_is_a_symmetry_of_its_physics_starts_and_reward(env_id, task):
    # the physics stepped from the flipped state with the flipped force must give the declared mirror image of what
    # it gives unflipped, paid and ended alike; and the flipped starts must be starts the task draws
    rng = np.random.default_rng(0)
    states = rng.normal(size=(400, 4)) * [1.5, 1.0, 2.0, 2.0]
    forces = rng.uniform(-1, 1, 400)
    after = PHYSICS.step(states.copy(), forces * C.max_force)
    flipped_after = PHYSICS.step(-states, -forces * C.max_force)
    mirror = lookup(env_id).mirror
    observations, actions = mirror(task.observe(after), forces[:, None].astype(np.float32))
    np.testing.assert_allclose(observations, task.observe(flipped_after), atol=1e-5)
    np.testing.assert_array_equal(actions, -forces[:, None].astype(np.float32))
    steps = np.arange(400) % task.horizon + 1
    for expected, got in zip(task.reward(after, steps), task.reward(flipped_after, steps), strict=True):
        np.testing.assert_allclose(got, expected, atol=1e-9)
    starts = task.sample_starts(rng, 200)
    angle_offset = np.pi if isinstance(task, SwingUpTask) else 0.0
    flipped_angles = np.mod(-starts[:, 2] - angle_offset + np.pi, 2 * np.pi) - np.pi + angle_offset
    assert (np.abs(-starts[:, 0]) <= task.start_high[0]).all()
    assert ((flipped_angles >= task.start_low[1]) & (flipped_angles <= task.start_high[1])).all()
