"""The one batched-environment interface: Gymnasium's ``VectorEnv``, made by one of five engines.

* ``native``: drrl's own environments, NumPy or MuJoCo batches (``gymnasium.make_vec`` returns them).
* ``numba``: Gymnasium's classic-control tasks compiled by Numba, Gymnasium's own episodes bit for bit, stepped in
  the caller's thread (``drrl.envs.compiled``).
* ``envpool``: EnvPool's C++ batches of Gymnasium's classic-control and MuJoCo tasks (``drrl.envs.pool``).
* ``gymnasium``: any other registered env with a 1-D Box observation (or discrete ones, seen one-hot) and a Box or
  Discrete action, one Gymnasium env per slot stepped in turn (``drrl.envs.serial``). Gymnasium's own native
  vector envs are not used: they take one reset seed for the whole batch, and drrl gives every episode its own.
* ``processes``: the same, the slots spread over one worker process per core (``drrl.envs.processes``), for envs
  whose steps are expensive; the same episodes as ``gymnasium``. Never chosen by ``auto``.

``auto`` picks the first that can run the id; a run records the engine it used in its config. ``ActionMap`` turns
a policy's raw outputs into actions of the env's action space. An ``EnvSource`` names a batched env so that
another process can make it: a registered id here, a learned model in ``drrl.models.imagined``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv

from drrl.envs import compiled, pool
from drrl.envs.processes import ProcessEpisodes
from drrl.envs.registry import is_own, lookup
from drrl.envs.serial import SerialEpisodes

ENGINES = ("auto", "native", "numba", "envpool", "gymnasium", "processes")


class EnvSource(Protocol):
    """Something a rollout process can rebuild a batched env from: small, picklable, made anew in each worker."""

    def make(self, num_envs: int) -> VectorEnv:
        """``num_envs`` sub-environments stepping together."""


@dataclass(frozen=True)
class RegisteredEnv:
    """A registered environment by its Gymnasium id (or drrl alias), batched by ``engine``, made with the keyword
    arguments ``options`` ((name, value) pairs)."""

    env_id: str
    engine: str = "auto"
    options: tuple[tuple[str, Any], ...] = ()

    def make(self, num_envs: int) -> VectorEnv:
        return make_batch_env(self.env_id, num_envs, self.engine, dict(self.options))


def resolve_env_id(name: str) -> str:
    """The Gymnasium id for ``name`` (an alias such as ``cartpole``, or any registered id)."""
    return lookup(name).env_id


def choose_engine(name: str, engine: str = "auto", with_options: bool = False) -> str:
    """The engine that batches env ``name``: ``engine`` itself if it can, the first that can for ``auto`` (neither
    Numba nor EnvPool if the env is to be made ``with_options``: they make their tasks as registered)."""
    env_id = resolve_env_id(name)
    native = is_own(env_id) and gymnasium.spec(env_id).vector_entry_point is not None
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; choose one of: {', '.join(ENGINES)}")
    if engine == "auto":
        if native:
            return "native"
        if not with_options and compiled.installed() and compiled.ships(env_id):
            return "numba"
        return "envpool" if not with_options and pool.installed() and pool.ships(env_id) else "gymnasium"
    if engine == "native" and not native:
        raise ValueError(f"{env_id} has no native drrl batch; its engines are numba, envpool, gymnasium and processes")
    if engine == "numba":
        if not compiled.installed():
            raise ValueError('engine numba is not installed; pip install "drrl[numba]"')
        if not compiled.ships(env_id):
            raise ValueError(f"engine numba compiles only {', '.join(compiled.TASKS)}; use engine gymnasium")
    if engine == "envpool":
        if not pool.installed():
            raise ValueError('engine envpool is not installed; pip install "drrl[envpool]"')
        if not pool.ships(env_id):
            raise ValueError(f"EnvPool has no {env_id}; use engine gymnasium")
    return engine


def make_batch_env(
    name: str, num_envs: int, engine: str = "auto", options: Mapping[str, Any] | None = None
) -> VectorEnv:
    """``num_envs`` copies of env ``name`` stepping together, made with the keyword arguments ``options``; raises
    before any work on unsupported spaces or options."""
    env_id = resolve_env_id(name)
    options = dict(options or {})
    engine = choose_engine(env_id, engine, bool(options))
    try:
        if engine == "native":
            env = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **options)
        elif engine == "numba":
            if options:
                raise ValueError(f"engine numba makes {env_id} as Gymnasium registers it, without options {options}")
            env = compiled.CompiledEpisodes(env_id, num_envs)
        elif engine == "envpool":
            if options:
                raise ValueError(f"engine envpool makes {env_id} as EnvPool ships it, without options {options}")
            env = pool.PooledEpisodes(env_id, num_envs)
        elif engine == "processes":
            env = ProcessEpisodes(env_id, num_envs, options)
        else:
            env = SerialEpisodes(env_id, num_envs, options)
    except (ImportError, gymnasium.error.DependencyNotInstalled) as error:
        raise cannot_be_made(env_id, error) from None
    except TypeError as error:  # a keyword argument the env does not take
        if not options:
            raise
        raise ValueError(f"{env_id} cannot be made with options {options}: {error}") from None
    try:
        if not is_frames(env.single_observation_space):
            observation_size(env.single_observation_space)
        ActionMap(env.single_action_space)
    except ValueError:
        env.close()
        raise
    return env


def cannot_be_made(env_id: str, error: Exception) -> ValueError:
    """The one-line error for ``env_id`` whose module or a package it needs failed to import (``error``)."""
    return ValueError(f"{env_id} cannot be made here: {missing_dependency(env_id, error)}")


def missing_dependency(env_id: str, error: Exception) -> str:
    """What is missing to make ``env_id``, and the pip command that installs it where Gymnasium names one."""
    entry_point = str(gymnasium.spec(env_id).entry_point)
    family = next(
        (name for name in ("mujoco", "box2d", "atari", "classic_control") if f".{name}." in f".{entry_point}."), None
    )
    hint = f'; pip install "gymnasium[{family}]"' if family else ""
    if isinstance(error, ModuleNotFoundError):
        return f"its module {error.name!r} is not installed{hint}"
    return f"{error}{hint if 'pip install' not in str(error) else ''}"


def is_frames(space: spaces.Space) -> bool:
    """Whether observations of ``space`` are stacked grey frames (F, H, W) of uint8 (``drrl.envs.pixels``); a
    model-based run encodes them (``drrl.models.frames``)."""
    return isinstance(space, spaces.Box) and space.dtype == np.uint8 and len(space.shape) == 3


def observation_size(space: spaces.Space) -> int:
    """The length of a 1-D Box observation; anything else is refused with a reason."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ValueError(
            f"unsupported observation space {space}; drrl needs a 1-D Box, or Discrete values or tuples or dicts of"
            " them (seen one-hot)"
        )
    return space.shape[0]


class ActionMap:
    """Raw policy outputs (N, size) → actions of a Box or Discrete space.

    Box with finite bounds: each output is clipped to [-1, 1] and scaled onto [low, high]. Box without bounds: passed
    through. Discrete(n): the policy has n outputs and the action is their argmax.
    """

    def __init__(self, space: spaces.Space):
        if isinstance(space, spaces.Discrete):
            self.size = int(space.n)
            self._start = int(space.start)
            self._discrete = True
            return
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"unsupported action space {space}; drrl needs a 1-D Box or a Discrete")
        self.size = space.shape[0]
        self._discrete = False
        self._dtype = space.dtype
        bounded = bool(np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high)))
        if bounded:
            self._half_range = torch.as_tensor((space.high - space.low) / 2, dtype=torch.float32)
            self._middle = torch.as_tensor((space.high + space.low) / 2, dtype=torch.float32)
            self._unit = bool(np.all(space.low == -1) and np.all(space.high == 1))
        self._bounded = bounded

    def __call__(self, raw: torch.Tensor) -> np.ndarray:
        if self._discrete:
            return (raw.argmax(dim=-1) + self._start).cpu().numpy()
        if not self._bounded:
            return raw.detach().cpu().numpy().astype(self._dtype, copy=False)
        action = raw.detach().clamp(-1.0, 1.0)
        if not self._unit:
            action = torch.addcmul(self._middle.to(action.device), action, self._half_range.to(action.device))
        return action.cpu().numpy().astype(self._dtype, copy=False)

    def raw(self, actions) -> np.ndarray:
        """The raw outputs (N, size) float32 that this map turns into ``actions``: a Discrete choice one-hot, a
        bounded Box's values scaled back onto [-1, 1], an unbounded Box's as they are."""
        if self._discrete:
            return np.eye(self.size, dtype=np.float32)[np.asarray(actions, dtype=np.int64).reshape(-1) - self._start]
        raw = np.asarray(actions, dtype=np.float32).reshape(-1, self.size)
        if self._bounded and not self._unit:
            raw = (raw - self._middle.numpy()) / self._half_range.numpy()
        return raw
