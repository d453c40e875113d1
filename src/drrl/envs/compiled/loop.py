"""The one compiled loop over a batch's slots, made for each task's ``advance`` and ``observe``."""

from __future__ import annotations

import functools
from collections.abc import Callable

import numba


@functools.cache
def step_running(advance: Callable, observe: Callable) -> Callable:
    """A compiled ``step(states, actions, horizon, elapsed, observations, rewards, terminated, truncated)`` that
    steps every slot whose episode runs with ``advance`` and writes its observation with ``observe``; an ended slot
    earns 0. An episode is truncated at ``horizon`` steps, as Gymnasium's TimeLimit does, even on the step it
    terminates. (The task's functions are compiled into the loop: passed as arguments, Numba would type them anew
    at every call, which costs more than the step.)"""

    @numba.njit
    def step(states, actions, horizon, elapsed, observations, rewards, terminated, truncated):
        for i in range(states.shape[0]):
            if terminated[i] or truncated[i]:
                rewards[i] = 0.0
                continue
            rewards[i], terminated[i] = advance(states[i], actions[i])
            elapsed[i] += 1
            truncated[i] = elapsed[i] >= horizon
            observe(states[i], observations[i])

    return step
