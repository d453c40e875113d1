"""MountainCar-v0 (Moore's mountain car): push left, nothing or right (0, 1, 2) to drive an underpowered car up
to the flag at x = 0.5; −1 a step."""

from __future__ import annotations

import math

import numba
import numpy as np

STATE_SIZE = 2  # position, velocity
MIN_POSITION, MAX_POSITION = -1.2, 0.6
MAX_SPEED = 0.07
GOAL_POSITION = 0.5
FORCE = 0.001
GRAVITY = 0.0025


def start(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A position uniform in [−0.6, −0.4] at rest, and its observation."""
    state = np.array([rng.uniform(low=-0.6, high=-0.4), 0])
    return state, state.astype(np.float32)


@numba.njit
def advance(state, action):
    position, velocity = state[0], state[1]
    velocity += (action - 1) * FORCE + math.cos(3 * position) * (-GRAVITY)
    velocity = min(max(velocity, -MAX_SPEED), MAX_SPEED)
    position += velocity
    position = min(max(position, MIN_POSITION), MAX_POSITION)
    if position == MIN_POSITION and velocity < 0:
        velocity = 0.0
    state[0], state[1] = position, velocity
    return -1.0, position >= GOAL_POSITION and velocity >= 0


@numba.njit
def observe(state, observation):
    observation[0] = state[0]
    observation[1] = state[1]
