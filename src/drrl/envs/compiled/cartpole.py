"""CartPole-v1 (Barto, Sutton and Anderson's cart-pole): a force of ±10 N pushes the cart, explicit Euler steps of
0.02 s; +1 a step until the pole leans past 12° or the cart leaves ±2.4 m."""

from __future__ import annotations

import math

import numba
import numpy as np

STATE_SIZE = 4  # x, ẋ, θ, θ̇
GRAVITY = 9.8
MASS_CART, MASS_POLE = 1.0, 0.1
TOTAL_MASS = MASS_POLE + MASS_CART
HALF_LENGTH = 0.5
POLE_MASS_LENGTH = MASS_POLE * HALF_LENGTH
FORCE = 10.0
TAU = 0.02
THETA_LIMIT = 12 * 2 * math.pi / 360
X_LIMIT = 2.4


def start(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """x, ẋ, θ, θ̇ each uniform in [−0.05, 0.05], and their observation."""
    state = rng.uniform(low=-0.05, high=0.05, size=(4,))
    return state, state.astype(np.float32)


@numba.njit
def advance(state, action):
    x, x_dot, theta, theta_dot = state[0], state[1], state[2], state[3]
    force = FORCE if action == 1 else -FORCE
    costheta = math.cos(theta)
    sintheta = math.sin(theta)
    temp = (force + POLE_MASS_LENGTH * theta_dot**2 * sintheta) / TOTAL_MASS
    thetaacc = (GRAVITY * sintheta - costheta * temp) / (
        HALF_LENGTH * (4.0 / 3.0 - MASS_POLE * costheta**2 / TOTAL_MASS)
    )
    xacc = temp - POLE_MASS_LENGTH * thetaacc * costheta / TOTAL_MASS
    state[0] = x + TAU * x_dot
    state[1] = x_dot + TAU * xacc
    state[2] = theta + TAU * theta_dot
    state[3] = theta_dot + TAU * thetaacc
    terminated = state[0] < -X_LIMIT or state[0] > X_LIMIT or state[2] < -THETA_LIMIT or state[2] > THETA_LIMIT
    return 1.0, terminated


@numba.njit
def observe(state, observation):
    for i in range(4):
        observation[i] = state[i]
