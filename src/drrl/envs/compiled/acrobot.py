"""Acrobot-v1 (Sutton and Barto's acrobot, Gymnasium's "book" dynamics): two links swung up by a torque of −1, 0
or +1 at their joint, integrated by one fourth-order Runge-Kutta step of 0.2 s; −1 a step until the tip is one link
above the base."""

from __future__ import annotations

import math

import numba
import numpy as np

from drrl.envs.compiled.libm import pow

STATE_SIZE = 4  # θ1, θ2, θ̇1, θ̇2
M1 = M2 = 1.0  # link masses
L1 = 1.0  # first link's length
LC1 = LC2 = 0.5  # the links' centres of mass
I1 = I2 = 1.0  # moments of inertia
G = 9.8
DT = 0.2
MAX_VEL_1, MAX_VEL_2 = 4 * math.pi, 9 * math.pi


def start(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """θ1, θ2, θ̇1, θ̇2 each uniform in [−0.1, 0.1], kept in float32 as Gymnasium keeps them, and their observation."""
    state = rng.uniform(low=-0.1, high=0.1, size=(4,)).astype(np.float32)
    return state, np.array([np.cos(state[0]), np.sin(state[0]), np.cos(state[1]), np.sin(state[1]), *state[2:]])


@numba.njit
def _accelerations(theta1, theta2, dtheta1, dtheta2, torque):
    """θ̈1, θ̈2 of the book's equations of motion."""
    d1 = M1 * LC1**2 + M2 * (L1**2 + LC2**2 + 2 * L1 * LC2 * math.cos(theta2)) + I1 + I2
    d2 = M2 * (LC2**2 + L1 * LC2 * math.cos(theta2)) + I2
    phi2 = M2 * LC2 * G * math.cos(theta1 + theta2 - math.pi / 2.0)
    phi1 = (
        -M2 * L1 * LC2 * pow(dtheta2, 2.0) * math.sin(theta2)
        - 2 * M2 * L1 * LC2 * dtheta2 * dtheta1 * math.sin(theta2)
        + (M1 * LC1 + M2 * L1) * G * math.cos(theta1 - math.pi / 2)
        + phi2
    )
    ddtheta2 = (torque + d2 / d1 * phi1 - M2 * L1 * LC2 * pow(dtheta1, 2.0) * math.sin(theta2) - phi2) / (
        M2 * LC2**2 + I2 - pow(d2, 2.0) / d1
    )
    ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
    return ddtheta1, ddtheta2


@numba.njit
def _wrap(x):
    """``x`` wrapped into [−π, π]."""
    while x > math.pi:
        x = x - 2 * math.pi
    while x < -math.pi:
        x = x + 2 * math.pi
    return x


@numba.njit
def advance(state, action):
    """One Runge-Kutta step of 0.2 s from ``state`` with torque ``action`` − 1, as Gymnasium's rk4 computes it
    (y + dt/6 (k1 + 2 k2 + 2 k3 + k4)), the angles wrapped into [−π, π] and the velocities bounded."""
    torque = float(action) - 1.0
    t1, t2, w1, w2 = state[0], state[1], state[2], state[3]
    half = DT / 2.0
    a1, a2 = _accelerations(t1, t2, w1, w2, torque)
    b1, b2 = _accelerations(t1 + half * w1, t2 + half * w2, w1 + half * a1, w2 + half * a2, torque)
    v1, v2 = w1 + half * a1, w2 + half * a2  # the second stage's velocities: k2's first two entries
    c1, c2 = _accelerations(t1 + half * v1, t2 + half * v2, w1 + half * b1, w2 + half * b2, torque)
    u1, u2 = w1 + half * b1, w2 + half * b2  # k3's
    d1, d2 = _accelerations(t1 + DT * u1, t2 + DT * u2, w1 + DT * c1, w2 + DT * c2, torque)
    x1, x2 = w1 + DT * c1, w2 + DT * c2  # k4's
    state[0] = _wrap(t1 + DT / 6.0 * (w1 + 2 * v1 + 2 * u1 + x1))
    state[1] = _wrap(t2 + DT / 6.0 * (w2 + 2 * v2 + 2 * u2 + x2))
    state[2] = min(max(w1 + DT / 6.0 * (a1 + 2 * b1 + 2 * c1 + d1), -MAX_VEL_1), MAX_VEL_1)
    state[3] = min(max(w2 + DT / 6.0 * (a2 + 2 * b2 + 2 * c2 + d2), -MAX_VEL_2), MAX_VEL_2)
    terminated = -math.cos(state[0]) - math.cos(state[1] + state[0]) > 1.0
    return (0.0 if terminated else -1.0), terminated


@numba.njit
def observe(state, observation):
    observation[0] = math.cos(state[0])
    observation[1] = math.sin(state[0])
    observation[2] = math.cos(state[1])
    observation[3] = math.sin(state[1])
    observation[4] = state[2]
    observation[5] = state[3]
