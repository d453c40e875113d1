"""MountainCarContinuous-v0: a force in [−1, 1] drives an underpowered car up to the flag at x = 0.45; 100 on
arrival, less 0.1 u² a step.

Gymnasium keeps the state in float32 after the first step and mixes float32 with Python floats, which NumPy rounds
to float32 before each operation; the reset's state is float64. This module computes each operation in the
precision Gymnasium does: the state's third entry says whether its values are still the reset's float64 ones, and
every intermediate carries whether it is a float32.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from drrl.envs.compiled.libm import pow

STATE_SIZE = 3  # position, velocity, 1 while they are the reset's float64 values (0 once float32)
MIN_POSITION, MAX_POSITION = -1.2, 0.6
MAX_SPEED = 0.07
GOAL_POSITION = 0.45
POWER = 0.0015


def start(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A position uniform in [−0.6, −0.4] at rest, and its observation."""
    state = np.array([rng.uniform(low=-0.6, high=-0.4), 0.0, 1.0])
    return state, state[:2].astype(np.float32)


@numba.njit
def _seen(number, narrow):
    """A Python float as NumPy meets it beside a float32 (if ``narrow``): rounded to float32 first."""
    return np.float64(np.float32(number)) if narrow else number


@numba.njit
def _add(x, y, narrow):
    """x + y for a float32 x (if ``narrow``) and a float32 or Python-float y: in float32 then, else in float64."""
    return np.float64(np.float32(x) + np.float32(y)) if narrow else x + y


@numba.njit
def advance(state, action):
    # every value is held as a float64; a float32 one (``narrow``) holds a float32's value exactly
    position, velocity, narrow = state[0], state[1], state[2] == 0.0
    u = np.float64(action[0])  # a float32
    if -1.0 <= u <= 1.0:
        push, push_narrow = np.float64(np.float32(u) * np.float32(POWER)), True
    else:  # Python's min and max return the bound itself, a Python float
        push, push_narrow = (1.0 if u > 1.0 else -1.0) * POWER, False
    slope = 0.0025 * math.cos(np.float64(np.float32(3) * np.float32(position)) if narrow else 3 * position)
    change = _add(push, -slope, push_narrow)
    velocity = _add(velocity, change, narrow)
    velocity_narrow = narrow
    if velocity > _seen(MAX_SPEED, velocity_narrow):
        velocity, velocity_narrow = MAX_SPEED, False
    if velocity < _seen(-MAX_SPEED, velocity_narrow):
        velocity, velocity_narrow = -MAX_SPEED, False
    position = _add(position, velocity, narrow)
    position_narrow = narrow
    if position > _seen(MAX_POSITION, position_narrow):
        position, position_narrow = MAX_POSITION, False
    if position < _seen(MIN_POSITION, position_narrow):
        position, position_narrow = MIN_POSITION, False
    if position == _seen(MIN_POSITION, position_narrow) and velocity < 0:
        velocity = 0.0
    terminated = position >= _seen(GOAL_POSITION, position_narrow) and velocity >= 0
    reward = (100.0 if terminated else 0.0) - pow(u, 2.0) * 0.1
    state[0], state[1], state[2] = np.float32(position), np.float32(velocity), 0.0
    return reward, terminated


@numba.njit
def observe(state, observation):
    observation[0] = state[0]
    observation[1] = state[1]
