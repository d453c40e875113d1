"""Any Gymnasium env that renders, seen through its camera: ``Pixels/ID`` observes what ``ID`` draws (thesis 6.1).

``Pixels/Pendulum-v1``, ``Pixels/InvertedPendulum-v5``, …: the env ``ID`` made with ``render_mode="rgb_array"``
(headless: MuJoCo on EGL or OSMesa, pygame on SDL's dummy driver), its observation replaced by its frames in the
layout of drrl's pixel cart-poles (``drrl.envs.pixels``): the previous and the current frame, grey, 64 × 64, uint8
of shape (2, 64, 64), the start's frame twice after a reset (Gymnasium's ``AddRenderObservation`` and
``FrameStackObservation``). A frame turns grey by ITU-R 601 luma and shrinks to 64 × 64 by averaging the pixels that
fall in each cell, so that thin shapes stay visible as fainter ones; Gymnasium's MuJoCo envs are asked to draw at
64 × 64 to begin with. Actions, rewards, ends, horizon and the task's verdict are ``ID``'s own.

An id of the family is registered with Gymnasium when it is first named (``drrl.envs.registry.register_family``),
in every process that names it. A model-based run encodes the frames (``drrl.models.frames``) and learns the reward
and end from the codes; a model-free run cannot read frames.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import load_env_creator
from gymnasium.wrappers import AddRenderObservation, FrameStackObservation

from drrl.envs.batch import cannot_be_made
from drrl.envs.baxter.model import import_mujoco
from drrl.envs.pixels import FRAME_SIZE, FRAMES
from drrl.envs.registry import EnvEntry, lookup, register, register_family
from drrl.envs.serial import make_env

PREFIX = "Pixels/"
LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)  # ITU-R BT.601


class GreyFrames(gymnasium.ObservationWrapper):
    """An env observing RGB frames (H, W, 3) made to observe grey ones (size, size), uint8, each pixel the mean of
    the pixels in its cell."""

    def __init__(self, env: gymnasium.Env, size: int = FRAME_SIZE):
        super().__init__(env)
        shape = env.observation_space.shape or ()
        if len(shape) != 3 or min(shape[:2]) < size:
            raise ValueError(f"RGB frames of shape {shape} are not (H, W, 3) or are smaller than {size} × {size}")
        height, width = shape[:2]
        self._rows, self._columns = (np.linspace(0, n, size + 1).astype(int) for n in (height, width))
        self._cells = np.outer(np.diff(self._rows), np.diff(self._columns)).astype(np.float32)
        self.observation_space = spaces.Box(0, 255, (size, size), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        grey = observation.astype(np.float32) @ LUMA
        sums = np.add.reduceat(np.add.reduceat(grey, self._rows[:-1], axis=0), self._columns[:-1], axis=1)
        return np.rint(sums / self._cells).astype(np.uint8)


def headless(env_id: str) -> None:
    """Set up headless drawing for ``env_id``, before its module is first imported."""
    if _is_mujoco(env_id):
        import_mujoco()  # a headless OpenGL unless MUJOCO_GL says otherwise, before Gymnasium imports MuJoCo
    # pygame's envs draw on surfaces in memory: no window, and no SDL complaint about a missing display session
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


def _is_mujoco(env_id: str) -> bool:
    return ".mujoco" in str(gymnasium.spec(env_id).entry_point)


def rendering_env(env_id: str, options: dict[str, Any] | None = None) -> gymnasium.Env:
    """``env_id`` made to draw rgb_array frames headless with ``options``; a ValueError saying why it cannot."""
    headless(env_id)
    try:
        return make_env(env_id, {"render_mode": "rgb_array", **(options or {})})
    except TypeError as error:  # an option this env does not take, e.g. shadows for the cart-pole
        raise ValueError(f"{env_id} cannot render with {options}: {error}") from None
    except (ImportError, gymnasium.error.DependencyNotInstalled) as error:
        raise cannot_be_made(env_id, error) from None


def following_env(env_id: str, options: dict[str, Any] | None = None) -> gymnasium.Env:
    """``rendering_env`` seen through the model's camera named "track" where it has one (Gymnasium's MuJoCo walkers,
    runners and swimmers: it follows the body's centre of mass, so a body that runs off stays in frame); Gymnasium
    falls back on its free camera where a model has none."""
    return rendering_env(env_id, {"camera_name": "track", **(options or {})} if _is_mujoco(env_id) else options)


def make_pixels(env_id: str, render_mode: str | None = None) -> gymnasium.Env:
    """``env_id`` observing its last two grey 64 × 64 frames; ``render_mode`` is always "rgb_array"."""
    env = rendering_env(env_id, {"width": FRAME_SIZE, "height": FRAME_SIZE} if _is_mujoco(env_id) else None)
    return FrameStackObservation(GreyFrames(AddRenderObservation(env)), FRAMES, padding_type="reset")


def pixel_member(env_id: str) -> None:
    """Register ``Pixels/ID`` with Gymnasium and drrl; a ValueError saying why if ``ID`` cannot be seen."""
    inner = lookup(env_id.removeprefix(PREFIX))
    if "/" in inner.env_id:
        raise ValueError(
            f"{env_id}: only ids without a namespace can be seen through the camera; drrl's cart-poles observe "
            "frames as cartpole-pixels and cartpole-swingup-pixels"
        )
    headless(inner.env_id)
    spec = gymnasium.spec(inner.env_id)
    try:
        creator = load_env_creator(spec.entry_point) if isinstance(spec.entry_point, str) else spec.entry_point
    except (ImportError, gymnasium.error.DependencyNotInstalled) as error:
        raise cannot_be_made(inner.env_id, error) from None
    if "rgb_array" not in getattr(creator, "metadata", {}).get("render_modes", ()):
        raise ValueError(f"{inner.env_id} does not render rgb_array frames, so {env_id} cannot observe them")
    entry = EnvEntry(env_id, verdict=inner.verdict, explain=inner.explain, end_reward=inner.end_reward)
    horizon = spec.max_episode_steps  # the inner env's own limit, for imagined episodes
    register(entry, f"{__name__}:make_pixels", kwargs={"env_id": inner.env_id}, max_episode_steps=horizon)


register_family(PREFIX, pixel_member)
