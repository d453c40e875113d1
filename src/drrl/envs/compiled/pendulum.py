"""Pendulum-v1: a torque in [−2, 2] swings a pendulum up and holds it there; the cost is θ² + 0.1 θ̇² + 0.001 u² a
step, θ normalised into [−π, π), over 200 steps. Where Gymnasium computes in float32 (the action's terms), so does
this."""

from __future__ import annotations

import math

import numba
import numpy as np

from drrl.envs.compiled.libm import pow, powf

STATE_SIZE = 2  # θ, θ̇
MAX_SPEED = 8
MAX_TORQUE = 2.0
DT = 0.05
G = 10.0
M = 1.0
L = 1.0


def start(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """θ uniform in [−π, π], θ̇ in [−1, 1], and their observation."""
    state = rng.uniform(low=-np.array([np.pi, 1.0]), high=np.array([np.pi, 1.0]))
    return state, np.array([np.cos(state[0]), np.sin(state[0]), state[1]], dtype=np.float32)


@numba.njit
def advance(state, action):
    theta, theta_dot = state[0], state[1]
    u = np.float32(min(max(action[0], np.float32(-MAX_TORQUE)), np.float32(MAX_TORQUE)))
    normalised = ((theta + np.pi) % (2 * np.pi)) - np.pi
    cost = pow(normalised, 2.0) + 0.1 * pow(theta_dot, 2.0) + np.float64(np.float32(0.001) * powf(u, 2.0))
    new_theta_dot = theta_dot + (3 * G / (2 * L) * math.sin(theta) + np.float64(np.float32(3.0 / (M * L**2)) * u)) * DT
    new_theta_dot = min(max(new_theta_dot, -MAX_SPEED), MAX_SPEED)
    state[0] = theta + new_theta_dot * DT
    state[1] = new_theta_dot
    return -cost, False


@numba.njit
def observe(state, observation):
    observation[0] = math.cos(state[0])
    observation[1] = math.sin(state[0])
    observation[2] = state[1]
