"""The cart-poles seen through a camera: small grey frames instead of the state (thesis 6.1, vision and control).

An observation is two 64 × 64 grey frames, the previous control period's and the current one's, uint8 of shape
(2, 64, 64) (frames first, as convolutions read channels): one frame shows where the cart and pole are, the pair how
they move (after a reset both are the start's frame, whose velocities are 0). In 0.02 s things move a fraction of a
pixel, so the pair's difference is faint; ``drrl.models.frames`` encodes each frame and reads the motion off the
difference of their codes. The camera is fixed: 6 m of track across the frame (the ±2.4 m bounds inside it), the
axle at mid-height, so a pole hanging down stays in view. Shapes are drawn with antialiased edges, each pixel the
share of it a shape covers, so a move of a fraction of a pixel (9.4 cm here) still changes the frame: the cart
mid-grey, the pole white, on black.

Everything else is the state env's: physics, starts, reward, ends and horizon. ``drrl/CartPolePixels-v0`` is the
thesis's balance task (5.8), ``drrl/CartPoleSwingUpPixels-v0`` the swing-up. A policy cannot read frames directly:
a model-based run encodes them into a latent state (``drrl.models.frames``) and searches a policy on that.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space

from drrl.envs.cartpole import (
    BalanceTask,
    CartPoleEnv,
    CartPoleVectorEnv,
    SwingUpTask,
    balance_verdict,
    explain_balance,
    explain_swing_up,
    failure_reward,
    swing_up_failure_reward,
    swing_up_verdict,
)

FRAME_SIZE = 64  # pixels a side
FRAMES = 2  # the previous frame and the current one
VIEW_HALF_WIDTH = 3.0  # metres of track either side of the centre
CART_HALF_WIDTH, CART_HALF_HEIGHT = 0.25, 0.12  # metres, as the state env draws it
CART_GREY, POLE_GREY = 0.5, 1.0


def draw_frames(states: np.ndarray, half_length: float = 0.5, size: int = FRAME_SIZE) -> np.ndarray:
    """Grey frames (N, size, size) uint8 of cart-pole states (N, 4), all drawn at once (in float32).

    Each shape is a signed distance field over the pixel centres (metres, negative inside); a pixel takes the share
    ½ − d / pixel of the shape, clipped to [0, 1] (antialiased edges one pixel wide). The pole is a segment from the
    axle of a pixel's width, so that it stays visible in a small frame.
    """
    pixel = 2 * VIEW_HALF_WIDTH / size
    centres = (np.arange(size, dtype=np.float32) + 0.5) * pixel - VIEW_HALF_WIDTH
    x, y = centres[None, None, :], -centres[None, :, None]  # (1, 1, W), (1, H, 1) metres, the axle at y = 0
    s, theta = (states[:, i, None, None].astype(np.float32) for i in (0, 2))
    dx = x - s
    qx, qy = np.abs(dx) - CART_HALF_WIDTH, np.abs(y) - CART_HALF_HEIGHT
    cart = np.hypot(np.maximum(qx, 0), np.maximum(qy, 0)) + np.minimum(np.maximum(qx, qy), 0)
    sin, cos = np.sin(theta), np.cos(theta)
    along = np.clip(dx * sin + y * cos, 0.0, 2 * half_length)  # the nearest point of the pole, along it
    pole = np.hypot(dx - along * sin, y - along * cos) - pixel / 2
    grey = np.maximum(CART_GREY * coverage(cart, pixel), POLE_GREY * coverage(pole, pixel))
    return np.rint(255 * grey).astype(np.uint8)


def coverage(distance: np.ndarray, pixel: float) -> np.ndarray:
    """The share of a pixel inside a shape, from the signed distance of its centre (antialiasing)."""
    return np.clip(0.5 - distance / pixel, 0.0, 1.0)


def frame_space() -> spaces.Box:
    return spaces.Box(0, 255, (FRAMES, FRAME_SIZE, FRAME_SIZE), np.uint8)


class CartPolePixelsVectorEnv(CartPoleVectorEnv):
    """``CartPoleVectorEnv`` observing each env's (previous, current) frames; everything else, seeds included, the
    same. An env that restarts shows its start frame twice."""

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, task=None, constants=None) -> None:
        super().__init__(num_envs, render_mode, task, constants)
        self.single_observation_space = frame_space()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._frames: np.ndarray | None = None
        self._restarting = np.zeros(num_envs, dtype=bool)

    def reset(self, *, seed=None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        self._frames = None
        return super().reset(seed=seed, options=options)

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        self._restarting = self._ended.copy()  # these restart on this step (next-step autoreset)
        return super().step(actions)

    def _observe(self) -> np.ndarray:
        assert self.state is not None
        current = draw_frames(self.state, self.physics.constants.half_length)
        if self._frames is None:
            self._frames = np.repeat(current[:, None], FRAMES, axis=1)
        else:
            self._frames[:, 0] = np.where(self._restarting[:, None, None], current, self._frames[:, 1])
            self._frames[:, 1] = current
        return self._frames.copy()


class CartPolePixelsEnv(CartPoleEnv):
    """``CartPoleEnv`` observing (previous, current) frames."""

    def __init__(self, render_mode: str | None = None, task=None, constants=None) -> None:
        super().__init__(render_mode, task, constants)
        self.observation_space = frame_space()
        self._frames: np.ndarray | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._frames = None
        return super().reset(seed=seed, options=options)

    def _observe(self) -> np.ndarray:
        assert self.state is not None
        current = draw_frames(self.state[None], self.physics.constants.half_length)[0]
        self._frames = np.stack([current if self._frames is None else self._frames[1], current])
        return self._frames.copy()


def _register() -> None:
    """drrl's entries for the cart-poles seen through the camera."""
    from drrl.envs.registry import EnvEntry, register

    for entry, task in (
        (
            EnvEntry(
                "drrl/CartPolePixels-v0",
                "cartpole-pixels",
                balance_verdict,
                explain_balance,
                end_reward=failure_reward,
            ),
            BalanceTask(),
        ),
        (
            EnvEntry(
                "drrl/CartPoleSwingUpPixels-v0",
                "cartpole-swingup-pixels",
                swing_up_verdict,
                explain_swing_up,
                end_reward=swing_up_failure_reward,
            ),
            SwingUpTask(),
        ),
    ):
        register(
            entry,
            "drrl.envs.pixels:CartPolePixelsEnv",
            "drrl.envs.pixels:CartPolePixelsVectorEnv",
            {"task": task},
        )


_register()
