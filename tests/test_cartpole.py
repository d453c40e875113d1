"""The cart-pole (thesis 5.1) against independent calculations, and its Gymnasium interface."""

from __future__ import annotations

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import drrl  # noqa: F401  (registers drrl/CartPole-v0)
from drrl.envs.cartpole import (
    BalanceTask,
    CartPoleConstants,
    CartPoleEnv,
    CartPolePhysics,
    CartPoleVectorEnv,
    render_frame,
    thesis_reward,
)

C = CartPoleConstants()
PHYSICS = CartPolePhysics(C)
M, m, l, g = C.cart_mass, C.pole_mass, C.half_length, C.gravity  # noqa: E741 (the thesis's l: half the pole)


def random_states(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-2, -3, -np.pi, -6], [2, 3, np.pi, 6], size=(n, 4))


# ---------------------------------------------------------------------------------------------------- physics


def test_constants_are_pybrains():
    assert (C.gravity, C.cart_mass, C.pole_mass, C.half_length, C.dt, C.max_force) == (9.81, 1.0, 0.1, 0.5, 0.02, 50.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        C.gravity = 10.0


def test_accelerations_solve_the_uniform_rod_lagrange_equations():
    """Lagrange's equations of cart (M) + uniform rod (m, centre at distance l, I = m(2l)²/12 about it), solved as
    the 2×2 linear system  [[M+m, ml cos θ], [ml cos θ, 4/3 ml²]] (s̈, θ̈) = (F + ml θ̇² sin θ, mgl sin θ)."""
    states = random_states(64)
    forces = np.random.default_rng(1).uniform(-50, 50, 64)
    cart, pole = PHYSICS.accelerations(states[:, 2], states[:, 3], forces)
    for (_, _, theta, theta_dot), force, s_ddot, theta_ddot in zip(states, forces, cart, pole, strict=True):
        mass_matrix = [[M + m, m * l * np.cos(theta)], [m * l * np.cos(theta), 4 / 3 * m * l**2]]
        generalised_forces = [force + m * l * theta_dot**2 * np.sin(theta), m * g * l * np.sin(theta)]
        np.testing.assert_allclose([s_ddot, theta_ddot], np.linalg.solve(mass_matrix, generalised_forces), rtol=1e-12)


def textbook_rk4(state: np.ndarray, force: np.ndarray, h: float) -> np.ndarray:
    k1 = PHYSICS.derivative(state, force)
    k2 = PHYSICS.derivative(state + h / 2 * k1, force)
    k3 = PHYSICS.derivative(state + h / 2 * k2, force)
    k4 = PHYSICS.derivative(state + h * k3, force)
    return state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def test_step_is_classic_rk4_over_one_control_period():
    states = random_states(32)
    forces = np.random.default_rng(2).uniform(-50, 50, 32)
    expected = textbook_rk4(states, forces, C.dt)
    stepped = PHYSICS.step(states.copy(), forces)
    np.testing.assert_allclose(stepped, expected, rtol=1e-12, atol=1e-12)


def mechanical_energy(states: np.ndarray) -> np.ndarray:
    """Cart ½Mṡ² + rod ½m|v_c|² + ½I θ̇² + mgl cos θ, with the rod's centre at (s + l sin θ, l cos θ), I = ml²/3."""
    _s, s_dot, theta, theta_dot = states.T
    return (
        0.5 * (M + m) * s_dot**2
        + m * l * np.cos(theta) * s_dot * theta_dot
        + 0.5 * (m * l**2 + m * l**2 / 3) * theta_dot**2
        + m * g * l * np.cos(theta)
    )


def horizontal_momentum(states: np.ndarray) -> np.ndarray:
    _s, s_dot, theta, theta_dot = states.T
    return (M + m) * s_dot + m * l * np.cos(theta) * theta_dot


# Large swings: a pole falling from near upright, one through the bottom, one spinning over the top.
SWINGS = np.array([[0.3, 0.5, 0.4, -1.0], [0.0, 0.0, 0.2, 0.0], [0.0, -1.0, 2.5, 3.0]])


def test_energy_and_momentum_are_conserved_without_force():
    """Over 2 s RK4 keeps both within 1e-6 (energies ~0.5 J); a point-mass pole (4/3 → 1) drifts by ~0.4 J."""
    states = SWINGS.copy()
    energy, momentum = mechanical_energy(states), horizontal_momentum(states)
    for _ in range(100):
        PHYSICS.step(states, np.zeros(len(states)))
        np.testing.assert_allclose(mechanical_energy(states), energy, atol=1e-5)
        np.testing.assert_allclose(horizontal_momentum(states), momentum, atol=1e-5)
    assert np.abs(states[:, 2] - SWINGS[:, 2]).min() > 1.0  # the poles really swung


def upright_linearisation() -> tuple[np.ndarray, np.ndarray]:
    """ẋ = A x + B F at the upright, from sin θ ≈ θ, cos θ ≈ 1, θ̇² ≈ 0 in the rod's equations:
    θ̈ = (g θ − F/(M+m)) / d with d = l(4/3 − m/(M+m)), and s̈ = F/(M+m) − ml θ̈ / (M+m)."""
    total = M + m
    d = l * (4 / 3 - m / total)
    A = np.array([[0, 1, 0, 0], [0, 0, -m * l * g / (total * d), 0], [0, 0, 0, 1], [0, 0, g / d, 0]])
    B = np.array([[0], [(1 + m * l / (total * d)) / total], [0], [-1 / (total * d)]])
    return A, B


def rk4_discretisation(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step of ẋ = Ax + Bu with u held:
    x' = (I + hA + (hA)²/2 + (hA)³/6 + (hA)⁴/24) x + h (I + hA/2 + (hA)²/6 + (hA)³/24) B u."""
    hA = h * A
    powers = [np.linalg.matrix_power(hA, k) for k in range(5)]
    Ad = powers[0] + powers[1] + powers[2] / 2 + powers[3] / 6 + powers[4] / 24
    Bd = h * (powers[0] + powers[1] / 2 + powers[2] / 6 + powers[3] / 24) @ B
    return Ad, Bd


def finite_difference_jacobians(f, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of f(states (1, 4), forces (1,)) -> (1, 4) at the upright with no force."""
    upright, no_force = np.zeros((1, 4)), np.zeros(1)
    columns = [(f(upright + eps * e, no_force) - f(upright - eps * e, no_force))[0] for e in np.eye(4)[:, None]]
    jac_state = np.column_stack(columns) / (2 * eps)
    jac_force = (f(upright, no_force + eps) - f(upright, no_force - eps))[0] / (2 * eps)
    return jac_state, jac_force[:, None]


def test_derivative_at_upright_matches_hand_linearisation():
    A, B = upright_linearisation()
    jac_state, jac_force = finite_difference_jacobians(PHYSICS.derivative)
    np.testing.assert_allclose(jac_state, A, atol=1e-7)
    np.testing.assert_allclose(jac_force, B, atol=1e-9)


def test_step_at_upright_matches_rk4_of_hand_linearisation():
    Ad, Bd = rk4_discretisation(*upright_linearisation(), C.dt)
    jac_state, jac_force = finite_difference_jacobians(lambda x, f: PHYSICS.step(x.copy(), f))
    np.testing.assert_allclose(jac_state, Ad, atol=1e-9)
    np.testing.assert_allclose(jac_force, Bd, atol=1e-12)


def test_rk4_is_fourth_order():
    """Halving the step over a fixed 0.8 s cuts the error ≈ 16×; errors estimated by Richardson differences."""
    start, force = np.array([[0.1, 0.5, 1.0, -2.0]]), np.array([20.0])

    def integrate(steps: int) -> np.ndarray:
        physics = CartPolePhysics(dataclasses.replace(C, dt=0.8 / steps))
        state = start.copy()
        for _ in range(steps):
            physics.step(state, force)
        return state

    coarse, medium, fine = integrate(8), integrate(16), integrate(32)
    order = np.log2(np.abs(coarse - medium).max() / np.abs(medium - fine).max())
    assert 3.5 < order < 4.5


# ---------------------------------------------------------------------------------------------------- reward 5.8


@pytest.mark.parametrize(
    ("s", "theta", "step", "reward", "terminated"),
    [
        (0.0, 0.0, 1, 0.0, False),
        (0.05, -0.05, 7, 0.0, False),  # the centre is inclusive
        (0.06, 0.0, 7, -1.0, False),
        (0.0, 0.3, 7, -1.0, False),  # centred in s but not in θ: inside the bounds
        (-2.4, 0.7, 7, -1.0, False),  # the bounds are inclusive
        (2.41, 0.0, 10, -380.0, True),  # −2·(200 − 10)
        (0.0, -0.71, 1, -398.0, True),
        (0.0, 0.71, 200, 0.0, True),
    ],
)
def test_thesis_reward_cases(s, theta, step, reward, terminated):
    state = np.array([[s, 9.0, theta, -9.0]])  # velocities play no part
    got_reward, got_terminated = thesis_reward(state, step)
    assert got_reward.tolist() == [reward]
    assert got_terminated.tolist() == [terminated]


def test_upright_rest_earns_zero_and_truncates_at_200():
    env = CartPoleVectorEnv(2)
    env.reset(seed=0)
    env.state[:] = 0.0  # an equilibrium: the state stays exactly 0
    for t in range(1, 201):
        _, reward, terminated, truncated, _ = env.step(np.zeros((2, 1)))
        assert reward.tolist() == [0.0, 0.0] and not terminated.any()
        assert truncated.tolist() == [t == 200] * 2


def test_leaving_the_bounds_costs_the_remaining_steps_and_terminates():
    env = CartPoleVectorEnv(1)
    env.reset(seed=0)
    env.state[:] = 0.0
    for _ in range(49):
        env.step(np.zeros((1, 1)))
    env.state[:] = [2.39, 2.0, 0.0, 0.0]  # crosses s = 2.4 within the next 0.02 s
    _, reward, terminated, truncated, _ = env.step(np.zeros((1, 1)))
    assert reward.tolist() == [-2.0 * (200 - 50)]
    assert terminated.tolist() == [True] and truncated.tolist() == [False]


# ---------------------------------------------------------------------------------------------------- Gymnasium


def test_check_env_passes_without_warnings():
    env = gym.make("drrl/CartPole-v0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    assert isinstance(env.unwrapped, CartPoleEnv)


def test_make_vec_returns_the_native_vector_env():
    env = gym.make_vec("drrl/CartPole-v0", num_envs=8)
    assert type(env) is CartPoleVectorEnv and env.unwrapped is env
    assert env.num_envs == 8
    assert env.observation_space.shape == (8, 4) and env.action_space.shape == (8, 1)
    obs, _ = env.reset(seed=0)
    obs, reward, terminated, truncated, _info = env.step(np.zeros((8, 1), dtype=np.float32))
    assert obs.dtype == np.float32 and obs in env.observation_space
    assert reward.dtype == np.float64 and terminated.dtype == truncated.dtype == bool


def test_seeded_reset_is_deterministic_and_follows_the_start_distribution():
    env = CartPoleVectorEnv(500)
    first, _ = env.reset(seed=3)
    again, _ = env.reset(seed=3)
    other, _ = env.reset(seed=4)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    assert np.all(np.abs(first[:, 0]) <= 0.5) and np.all(np.abs(first[:, 2]) <= 0.2)
    assert np.abs(first[:, 0]).max() > 0.45 and np.abs(first[:, 2]).max() > 0.18  # spread over the whole range
    assert np.all(first[:, 1::2] == 0.0)


def nth_start(seed: int, n: int) -> np.ndarray:
    """The n-th start (1-based) that np.random.default_rng(seed) gives, as an observation."""
    rng = np.random.default_rng(seed)
    return [BalanceTask().sample_starts(rng, 1)[0] for _ in range(n)][-1].astype(np.float32)


def test_per_env_seeds_do_not_depend_on_the_batch():
    starts_abc, _ = CartPoleVectorEnv(3).reset(seed=[11, 22, 33])
    for i, seed in enumerate([11, 22, 33]):
        alone, _ = CartPoleVectorEnv(1).reset(seed=[seed])
        np.testing.assert_array_equal(starts_abc[i], alone[0])
    env = CartPoleVectorEnv(2)
    shuffled, _ = env.reset(seed=[33, 11])
    np.testing.assert_array_equal(shuffled, starts_abc[[2, 0]])
    unseeded, _ = env.reset()  # goes on with each env's own generator
    np.testing.assert_array_equal(unseeded, [nth_start(33, 2), nth_start(11, 2)])


def test_single_env_matches_vector_env_with_the_same_seed():
    single, vector = CartPoleEnv(), CartPoleVectorEnv(1)
    obs_single, _ = single.reset(seed=5)
    obs_vector, _ = vector.reset(seed=[5])
    for _ in range(50):
        np.testing.assert_array_equal(obs_single, obs_vector[0])
        action = np.clip(obs_single @ np.float32([0.1, 0.3, 5.0, 0.8]), -1, 1)  # a crude balancing feedback
        obs_single, reward, terminated, *_ = single.step(action[None])
        obs_vector, rewards, *_ = vector.step(action[None, None])
        assert reward == rewards[0] and not terminated


def test_next_step_autoreset_draws_from_each_envs_own_generator():
    env = CartPoleVectorEnv(3)
    obs, _ = env.reset(seed=[8, 8, 9])  # envs 0 and 1 share a seed
    np.testing.assert_array_equal(obs[0], obs[1])
    env.state[1] = [0.0, 0.0, 0.69, 5.0]  # env 1 falls over in the next step
    _, reward, terminated, truncated, _ = env.step(np.zeros((3, 1)))
    assert terminated.tolist() == [False, True, False] and not truncated.any()
    assert reward[1] == -2.0 * (200 - 1)

    obs, reward, terminated, truncated, _ = env.step(np.ones((3, 1)))  # env 1's action is ignored
    np.testing.assert_array_equal(obs[1], nth_start(8, 2))
    assert reward[1] == 0.0 and not terminated[1] and not truncated[1]
    assert env.elapsed_steps.tolist() == [2, 0, 2]
    assert np.all(obs[[0, 2], 1] != 0.0)  # the others were pushed

    env.state[0] = [0.0, 0.0, -0.69, -5.0]  # now env 0 falls over: its second start is env 1's
    _, _, terminated, _, _ = env.step(np.zeros((3, 1)))
    assert terminated.tolist() == [True, False, False] and env.elapsed_steps.tolist() == [3, 1, 3]
    obs, *_ = env.step(np.zeros((3, 1)))
    np.testing.assert_array_equal(obs[0], nth_start(8, 2))
    assert env.elapsed_steps.tolist() == [0, 2, 4]


def test_bad_action_shapes_raise():
    env = CartPoleVectorEnv(4)
    env.reset(seed=0)
    for actions in (np.zeros(4), np.zeros((4, 2)), np.zeros((3, 1))):
        with pytest.raises(ValueError, match=r"shape \(4, 1\)"):
            env.step(actions)
    single = CartPoleEnv()
    single.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(1,\)"):
        single.step(np.zeros((1, 1)))


def test_non_finite_actions_raise_naming_the_envs():
    env = CartPoleVectorEnv(5)
    env.reset(seed=0)
    actions = np.zeros((5, 1))
    actions[1], actions[3] = np.nan, -np.inf
    with pytest.raises(ValueError, match=r"envs \[1, 3\]"):
        env.step(actions)
    single = CartPoleEnv()
    single.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite"):
        single.step(np.array([np.inf]))


def test_actions_are_clipped_to_one():
    env = CartPoleVectorEnv(2)
    env.reset(seed=0)
    env.state[:] = 0.0
    obs, *_ = env.step(np.array([[1.0], [7.0]]))
    np.testing.assert_array_equal(obs[0], obs[1])


# ---------------------------------------------------------------------------------------------------- rendering


def ink(frame: np.ndarray) -> np.ndarray:
    """Where anything but the white background is drawn."""
    return np.any(frame != 255, axis=-1)


def test_render_draws_the_pole_where_it_leans():
    upright = render_frame(np.array([0.0, 0.0, 0.0, 0.0]))
    leaning = render_frame(np.array([0.0, 0.0, 0.5, 0.0]))
    assert upright.shape == (400, 600, 3) and upright.dtype == np.uint8
    above_cart = ink(leaning[:200])  # the axle is at row 240, the cart reaches up to row 228
    assert above_cart[:, 300:].sum() > 100 and above_cart[:, :300].sum() == 0  # θ > 0 leans towards +s
    assert ink(upright[:200])[:, 300:].sum() == ink(upright[:200])[:, :300].sum()  # upright is symmetric


def test_render_moves_with_the_cart():
    left = ink(render_frame(np.array([-1.0, 0.0, 0.0, 0.0])))
    right = ink(render_frame(np.array([1.0, 0.0, 0.0, 0.0])))
    columns = np.arange(600)
    assert (right[:200] * columns).sum() / right[:200].sum() - (left[:200] * columns).sum() / left[:200].sum() == 200


def test_envs_render_frames():
    vector = CartPoleVectorEnv(3, render_mode="rgb_array")
    vector.reset(seed=0)
    frames = vector.render()
    assert isinstance(frames, tuple) and len(frames) == 3
    assert all(frame.shape == (400, 600, 3) and frame.dtype == np.uint8 for frame in frames)
    single = gym.make("drrl/CartPole-v0", render_mode="rgb_array")
    single.reset(seed=0)
    assert single.render().shape == (400, 600, 3)
    with pytest.raises(ValueError, match="render_mode"):
        CartPoleVectorEnv(2, render_mode="human")


# ---------------------------------------------------------------------------------------------------- sanity: LQR


def discrete_lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """K of u = −K x from the discrete algebraic Riccati equation, by plain fixed-point iteration."""
    P = Q
    for _ in range(5000):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P_next = Q + A.T @ P @ (A - B @ K)
        if np.allclose(P_next, P, rtol=1e-12, atol=0):
            return K
        P = P_next
    raise AssertionError("the Riccati iteration did not converge")


def test_lqr_at_upright_balances_all_50_starts():
    """The reference: LQR on the upright linearisation (Q = diag(1000, 1, 1000, 1), R = 0.1 on the force in N,
    clipped to ±50 N) balances all 50 starts with a mean return of −41.3 (here about −40, depending on the starts)."""
    Ad, Bd = rk4_discretisation(*upright_linearisation(), C.dt)
    gain = discrete_lqr_gain(Ad, Bd, np.diag([1000.0, 1.0, 1000.0, 1.0]), np.array([[0.1]]))
    env = CartPoleVectorEnv(50)
    obs, _ = env.reset(seed=2015)
    returns = np.zeros(50)
    for _ in range(200):
        force = -obs.astype(np.float64) @ gain.T
        obs, reward, terminated, truncated, _ = env.step(np.clip(force / C.max_force, -1.0, 1.0))
        assert not terminated.any()
        returns += reward
    assert truncated.all()
    assert -50.0 < returns.mean() < -32.0


def test_the_balance_verdict_says_what_each_criterion_needs():
    from drrl.envs.cartpole import balance_verdict, explain_balance

    returns, ended = torch.full((1, 50), -45.1), torch.zeros(1, 50, dtype=torch.bool)
    ended[0, 0] = True  # 49 of 50 up, a mean return above -50: neither balanced nor near-optimal
    assert balance_verdict(returns, ended) == {"balanced": False, "near_optimal": False}
    explained = explain_balance(returns, ended)
    assert "49/50 episodes kept the pole up" in explained and "balanced needs all 50" in explained
    assert "near-optimal needs balanced and a mean return ≥ -50" in explained
