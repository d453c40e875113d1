"""The thesis's cart-pole (Gao 2015, section 5.1) as a fast batched NumPy environment.

Physics. PyBrain's constants (the thesis ran PyBrain's cart-pole) with a uniform rod on a frictionless cart,
integrated by classic Runge-Kutta 4 over one control period with the force held constant. The equations of motion
are those of Florian (2007), "Correct equations for the dynamics of the cart-pole system" (the same as
Gymnasium's CartPole). The thesis's own 5.6-5.7 come from a point-mass Lagrangian and carry typos (5.6 has
½·m·l²·θ̇² where a term m·l·θ̇²·sin θ belongs, and a gravity term m·g·l·cos θ that has no place in the horizontal
equation), so we do not use them.

State, in the thesis's order: (s, ṡ, θ, θ̇) = cart position, cart velocity, pole angle from upright (positive
leaning towards +s), angular velocity. An action in [-1, 1] is clipped and scaled to a force of ±50 N.

Tasks are small objects (start distribution, observation, reward and termination) so that variants slot in next
to ``BalanceTask`` without touching the physics or the environments:

* ``BalanceTask`` (``drrl/CartPole-v0``): the thesis's task, 5.1 with the reward 5.8, T = 200 steps (4 s).
* ``PartiallyObservedTask`` (``drrl/CartPolePO-v0``): the same task observing only (s, θ). The velocities are
  hidden, so the environment is a POMDP (thesis 2.1.1) and a policy must infer them from what it has seen.
  Solved means the same as for the balance task. Note that "balanced" alone does not need memory: the static
  feedback a = 0.25·θ keeps every start inside the bounds for 200 steps, swinging undamped (a static feedback of
  (s, θ) cannot damp the pole: the linearised loop has no velocity terms). Reaching the centre, which the reward
  pays for and "near-optimal" asks, needs the velocities.
* ``SwingUpTask`` (``drrl/CartPoleSwingUp-v0``): the pole starts hanging down and must be swung up and held
  upright, the model-based benchmark of PILCO and PETS, on the thesis's cart (±50 N). See its docstring for the
  start, observation, reward, horizon and what "solved" means.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

# ---------------------------------------------------------------------------------------------------- physics


@dataclass(frozen=True)
class CartPoleConstants:
    """PyBrain's cart-pole constants (SI units); the pole is a uniform rod of length 2·half_length."""

    gravity: float = 9.81
    cart_mass: float = 1.0
    pole_mass: float = 0.1
    half_length: float = 0.5
    dt: float = 0.02  # control period, one RK4 step
    max_force: float = 50.0  # the force of action ±1

    @property
    def total_mass(self) -> float:
        return self.cart_mass + self.pole_mass


class CartPolePhysics:
    """Batched equations of motion and their RK4 step; states are float64 arrays of shape (N, 4)."""

    def __init__(self, constants: CartPoleConstants = CartPoleConstants()) -> None:
        self.constants = c = constants
        # Coefficients as 0-d float64 arrays: NumPy combines them with arrays faster than it does Python floats.
        coefficient = partial(np.array, dtype=np.float64)
        self._inverse_total_mass = coefficient(1.0 / c.total_mass)
        self._mass_length_ratio = coefficient(c.pole_mass * c.half_length / c.total_mass)  # m·l / (M + m)
        self._four_thirds_length = coefficient(4.0 / 3.0 * c.half_length)
        self._gravity = coefficient(c.gravity)
        self._dt, self._half_dt = coefficient(c.dt), coefficient(c.dt / 2)
        self._dt_sixth, self._dt_squared_sixth = coefficient(c.dt / 6), coefficient(c.dt * c.dt / 6)
        self._two = coefficient(2.0)

    def accelerations(self, theta, theta_dot, force):
        """(s̈, θ̈) of Florian (2007) for arrays of θ, θ̇ and force F in newtons."""
        return self._accelerations(theta, theta_dot, force * self._inverse_total_mass)

    def derivative(self, state: np.ndarray, force) -> np.ndarray:
        """d/dt (s, ṡ, θ, θ̇) for states (N, 4) and forces (N,) in newtons."""
        cart, pole = self.accelerations(state[:, 2], state[:, 3], force)
        return np.stack([state[:, 1], cart, state[:, 3], pole], axis=1)

    def step(self, state: np.ndarray, force) -> np.ndarray:
        """Advance ``state`` (N, 4) in place by one control period with classic RK4; returns it.

        The accelerations depend only on θ, θ̇ and the (constant) force, so the stages need only θ and θ̇, and the
        RK4 sums for the positions collapse to x + h·ẋ + h²/6·(ẍ₁ + ẍ₂ + ẍ₃). This is exactly classic RK4 on the
        four-dimensional state, with far fewer array operations.
        """
        s, s_dot, theta, theta_dot = state.T  # views: updated in place below
        h, half_h, two = self._dt, self._half_dt, self._two
        push = force * self._inverse_total_mass
        a1, alpha1 = self._accelerations(theta, theta_dot, push)
        w2 = theta_dot + half_h * alpha1
        a2, alpha2 = self._accelerations(theta + half_h * theta_dot, w2, push)
        w3 = theta_dot + half_h * alpha2
        a3, alpha3 = self._accelerations(theta + half_h * w2, w3, push)
        w4 = theta_dot + h * alpha3
        a4, alpha4 = self._accelerations(theta + h * w3, w4, push)
        s += h * s_dot + self._dt_squared_sixth * (a1 + a2 + a3)
        theta += h * theta_dot + self._dt_squared_sixth * (alpha1 + alpha2 + alpha3)
        s_dot += self._dt_sixth * (a1 + two * (a2 + a3) + a4)
        theta_dot += self._dt_sixth * (alpha1 + two * (alpha2 + alpha3) + alpha4)
        return state

    def _accelerations(self, theta, theta_dot, push):
        """Florian's equations with push = F / (M + m):

        temp = push + m·l·θ̇²·sin θ / (M + m)
        θ̈    = (g·sin θ − cos θ·temp) / (l·(4/3 − m·cos²θ / (M + m)))
        s̈    = temp − m·l·θ̈·cos θ / (M + m)
        """
        sin, cos = np.sin(theta), np.cos(theta)
        temp = self._mass_length_ratio * theta_dot * theta_dot * sin + push
        ratio_cos = self._mass_length_ratio * cos
        theta_ddot = (self._gravity * sin - cos * temp) / (self._four_thirds_length - ratio_cos * cos)
        return temp - ratio_cos * theta_ddot, theta_ddot


# ---------------------------------------------------------------------------------------------------- tasks

CENTRE_TOLERANCE = 0.05  # |s| and |θ| within which the thesis's reward is 0
POSITION_LIMIT = 2.4  # |s| beyond which the episode fails
ANGLE_LIMIT = 0.7  # |θ| beyond which the episode fails


def thesis_reward(state: np.ndarray, step, horizon: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """The thesis's reward (5.8) at 1-based step ``step``, after the transition, for states (N, 4).

    Returns (reward, terminated): 0 near the centre (|s|, |θ| ≤ 0.05), −1 elsewhere inside the bounds
    (|s| ≤ 2.4, |θ| ≤ 0.7), and −2·(T − t) on leaving them, which ends the episode. The thesis writes the middle
    case as 2.4 ≥ |s| ≥ 0.05 and 0.7 ≥ |θ| ≥ 0.05, leaving e.g. |s| ≤ 0.05 < |θ| to "otherwise"; we read it as
    "inside the bounds but not centred", the only reading under which "otherwise" means failure.
    """
    s, theta = np.abs(state[:, 0]), np.abs(state[:, 2])
    inside = (s <= POSITION_LIMIT) & (theta <= ANGLE_LIMIT)
    centred = (s <= CENTRE_TOLERANCE) & (theta <= CENTRE_TOLERANCE)
    reward = centred - 1.0  # 0 when centred, else −1
    terminated = ~inside
    if terminated.any():
        reward = np.where(terminated, failure_reward(step, horizon), reward)
    return reward, terminated


class CartPoleTask(Protocol):
    """What the environments need from a task. Variants (partially observed, swing-up) provide the same."""

    @property
    def horizon(self) -> int:
        """Steps after which an episode is truncated."""

    @property
    def observation_size(self) -> int:
        """The length of an observation."""

    def sample_starts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n start states (n, 4), float64."""

    def observe(self, state: np.ndarray) -> np.ndarray:
        """Observations (N, observation_size), float32, of states (N, 4): a fresh array."""

    def reward(self, state: np.ndarray, step) -> tuple[np.ndarray, np.ndarray]:
        """(reward float64 (N,), terminated bool (N,)) after the transition into ``state`` at 1-based ``step``."""


@dataclass(frozen=True)
class BalanceTask:
    """Balance the pole from near upright for T steps (thesis 5.1), fully observed, reward 5.8."""

    horizon: int = 200
    observation_size: ClassVar[int] = 4
    start_low: ClassVar[np.ndarray] = np.array([-0.5, -0.2])  # (s, θ); both velocities start at 0
    start_high: ClassVar[np.ndarray] = np.array([0.5, 0.2])

    def sample_starts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n start states (n, 4): s ~ U(-0.5, 0.5), θ ~ U(-0.2, 0.2), velocities 0."""
        starts = np.zeros((n, 4))
        # low + (high − low)·U[0, 1) is what rng.uniform computes, without its overhead of several µs a call
        starts[:, 0::2] = self.start_low + (self.start_high - self.start_low) * rng.random((n, 2))
        return starts

    def observe(self, state: np.ndarray) -> np.ndarray:
        """The whole state (s, ṡ, θ, θ̇) as float32, a fresh array."""
        return state.astype(np.float32)

    def reward(self, state: np.ndarray, step) -> tuple[np.ndarray, np.ndarray]:
        """(reward, terminated) of the thesis's formula 5.8."""
        return thesis_reward(state, step, self.horizon)


@dataclass(frozen=True)
class PartiallyObservedTask(BalanceTask):
    """The balance task observing only (s, θ): cart position and pole angle, velocities hidden (thesis 2.1.1)."""

    observation_size: ClassVar[int] = 2

    def observe(self, state: np.ndarray) -> np.ndarray:
        """(s, θ) as float32, a fresh array."""
        return state[:, 0::2].astype(np.float32)


SWING_UP_CART_WEIGHT = 0.25  # the cost of the cart at a track end, in units of the upright reward
SWING_UP_SOLVED_RETURN = 160.0  # of at most 250: see SwingUpTask


@dataclass(frozen=True)
class SwingUpTask:
    """Swing the pole up from hanging down and hold it upright, the cart staying on the track.

    Start: s ~ U(-0.2, 0.2), θ ~ π + U(-0.2, 0.2) (hanging down), velocities 0.
    Observation: (s, ṡ, sin θ, cos θ, θ̇), float32. The angle is given by its sine and cosine: θ itself is not
    bounded (the pole may turn over) and a policy should not see a jump at ±π.
    Reward at step t, after the transition (r_t ∈ [-0.25, 1]):

        r_t = ½·(1 + cos θ) − 0.25·(s / 2.4)²      on the track, |s| ≤ 2.4
        r_t = −(T − t)                              on leaving it; the episode ends there

    ½·(1 + cos θ) is 1 upright and 0 hanging: a dense signal all the way up, so that a search from scratch has a
    slope to climb. The cart term keeps the cart near the centre. Leaving the track costs 1 per remaining step,
    more than any step on the track, so that ending the episode never pays (as 5.8's −2·(T − t) does).
    Horizon: T = 250 steps (5 s at dt = 0.02): time to swing up (about 1–2 s with ±50 N) and to show the pole held.
    Solved (``swing_up_verdict``): in 50 of 50 evaluation episodes the cart stays on the
    track and the return is at least 160 (of at most 250). Hanging still earns about 0 and a pole that keeps
    turning over earns about half a point a step (≈ 125), so ≥ 160 needs the pole near the top most of the time.
    """

    horizon: int = 250
    observation_size: ClassVar[int] = 5
    start_low: ClassVar[np.ndarray] = np.array([-0.2, np.pi - 0.2])  # (s, θ); both velocities start at 0
    start_high: ClassVar[np.ndarray] = np.array([0.2, np.pi + 0.2])

    def sample_starts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n start states (n, 4): s ~ U(-0.2, 0.2), θ ~ U(π − 0.2, π + 0.2), velocities 0."""
        starts = np.zeros((n, 4))
        starts[:, 0::2] = self.start_low + (self.start_high - self.start_low) * rng.random((n, 2))
        return starts

    def observe(self, state: np.ndarray) -> np.ndarray:
        """(s, ṡ, sin θ, cos θ, θ̇) as float32."""
        theta = state[:, 2]
        return np.stack([state[:, 0], state[:, 1], np.sin(theta), np.cos(theta), state[:, 3]], 1).astype(np.float32)

    def reward(self, state: np.ndarray, step) -> tuple[np.ndarray, np.ndarray]:
        """(reward, terminated) as in the class docstring."""
        s = state[:, 0]
        reward = 0.5 * (1.0 + np.cos(state[:, 2])) - SWING_UP_CART_WEIGHT * (s / POSITION_LIMIT) ** 2
        terminated = np.abs(s) > POSITION_LIMIT
        if terminated.any():
            reward = np.where(terminated, swing_up_failure_reward(step, self.horizon), reward)
        return reward, terminated


def _observation_space(task: CartPoleTask) -> spaces.Box:
    # The state is unbounded; float32's largest value instead of inf keeps Gymnasium's checker quiet.
    bound = np.finfo(np.float32).max
    return spaces.Box(-bound, bound, (task.observation_size,), np.float32)


# ---------------------------------------------------------------------------------------------------- environments

_METADATA = {"render_modes": ["rgb_array"], "render_fps": 50}  # 50 fps = one frame per 0.02 s control period


def _check_render_mode(render_mode: str | None) -> str | None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    return render_mode


def _forces(actions: np.ndarray, max_force: float) -> np.ndarray:
    """Actions (N, 1), already validated, clipped to [-1, 1] and scaled to forces (N,) in newtons."""
    return actions[:, 0].clip(-1.0, 1.0) * max_force


class _SeededStarts:
    """Env i's starts, drawn from its own generator ``np.random.default_rng(seeds[i])`` and nothing else.

    Making a generator costs ~20 µs, a lot beside a step of a whole batch, and batches often repeat seeds (common
    random numbers: every candidate's episode e starts alike). So envs sharing a seed share their first start, drawn
    once, and an env gets its own generator only when it needs a second start, advanced past the first: the same
    numbers as eager generators, for one generator per distinct seed at reset.
    """

    def __init__(self, task: CartPoleTask, seeds: Sequence[int]) -> None:
        self._task = task
        self._seeds = [int(seed) for seed in seeds]
        self._rngs: list[np.random.Generator | None] = [None] * len(self._seeds)

    def first(self) -> np.ndarray:
        """Every env's first start, (num_envs, 4)."""
        starts = {seed: self._task.sample_starts(np.random.default_rng(seed), 1) for seed in set(self._seeds)}
        return np.concatenate([starts[seed] for seed in self._seeds])

    def next(self, indices: np.ndarray) -> np.ndarray:
        """The next start of each env in ``indices``."""
        return np.concatenate([self._task.sample_starts(self._rng(i), 1) for i in indices])

    def _rng(self, i: int) -> np.random.Generator:
        rng = self._rngs[i]
        if rng is None:
            rng = self._rngs[i] = np.random.default_rng(self._seeds[i])
            self._task.sample_starts(rng, 1)  # the first start, handed out by first()
        return rng


class CartPoleVectorEnv(gym.vector.VectorEnv):
    """num_envs cart-poles stepped together as one NumPy batch, with next-step autoreset.

    ``reset(seed=int)`` seeds one generator for all starts and autoresets of the batch; ``reset(seed=[s_0, ...])``
    gives env i its own generator ``np.random.default_rng(s_i)``, so that its starts depend only on s_i and not on
    the batch it sits in. ``state`` holds the raw float64 states (num_envs, 4).
    """

    metadata = {**_METADATA, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        task: CartPoleTask | None = None,
        constants: CartPoleConstants | None = None,
    ) -> None:
        self.num_envs = num_envs
        self.render_mode = _check_render_mode(render_mode)
        self.task: CartPoleTask = task if task is not None else BalanceTask()
        self.physics = CartPolePhysics(constants if constants is not None else CartPoleConstants())
        self.single_observation_space = _observation_space(self.task)
        self.single_action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.state: np.ndarray | None = None
        self.elapsed_steps = np.zeros(num_envs, dtype=np.int64)
        self._seeded_starts: _SeededStarts | None = None
        self._ended = np.zeros(num_envs, dtype=bool)  # ended on the previous step: reset on this one

    def reset(
        self,
        *,
        seed: int | Sequence[int] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env afresh.

        ``seed``: one int for the whole batch, one int per env, or None to go on drawing from the current
        generator(s) (a fresh random one if never seeded). ``options`` are not used.
        """
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
            self._seeded_starts = None
            self.state = self.task.sample_starts(self.np_random, self.num_envs)
        elif seed is not None:
            if len(seed) != self.num_envs:
                raise ValueError(f"expected one seed per env ({self.num_envs}), got {len(seed)}")
            self._seeded_starts = _SeededStarts(self.task, seed)
            self.state = self._seeded_starts.first()
        else:
            self.state = self._sample_starts(np.arange(self.num_envs))
        self.elapsed_steps[:] = 0
        self._ended[:] = False
        return self._observe(), {}

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One control period for every env; envs that ended on the previous step restart instead.

        A restarting env returns its start observation, reward 0, terminated and truncated False; its action is
        ignored (Gymnasium's next-step autoreset). An env leaving the bounds at step T is both terminated and
        truncated.
        """
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        actions = self._checked(actions)
        self.physics.step(self.state, _forces(actions, self.physics.constants.max_force))
        self.elapsed_steps += 1
        reward, terminated = self.task.reward(self.state, self.elapsed_steps)
        truncated = self.elapsed_steps >= self.task.horizon
        restarting = self._ended.nonzero()[0]
        if restarting.size:
            self.state[restarting] = self._sample_starts(restarting)
            self.elapsed_steps[restarting] = 0
            reward[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
        self._ended = terminated | truncated
        return self._observe(), reward, terminated, truncated, {}

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB frame (400, 600, 3) per env, or None without render_mode 'rgb_array'."""
        if self.render_mode is None or self.state is None:
            return None
        half_length = self.physics.constants.half_length
        return tuple(render_frame(state, half_length) for state in self.state)

    def _observe(self) -> np.ndarray:
        """Every env's observation of its state (the camera's envs draw frames instead)."""
        assert self.state is not None
        return self.task.observe(self.state)

    def _sample_starts(self, indices: np.ndarray) -> np.ndarray:
        if self._seeded_starts is None:
            return self.task.sample_starts(self.np_random, len(indices))
        return self._seeded_starts.next(indices)

    def _checked(self, actions) -> np.ndarray:
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, 1):
            raise ValueError(f"expected actions of shape ({self.num_envs}, 1), got {actions.shape}")
        finite = np.isfinite(actions)
        if not finite.all():
            raise ValueError(f"non-finite actions for envs {np.flatnonzero(~finite[:, 0]).tolist()}")
        return actions


class CartPoleEnv(gym.Env):
    """A single cart-pole: the same physics and task as ``CartPoleVectorEnv`` with one env, no autoreset.

    ``state`` holds the raw float64 state (4,).
    """

    metadata = _METADATA

    def __init__(
        self,
        render_mode: str | None = None,
        task: CartPoleTask | None = None,
        constants: CartPoleConstants | None = None,
    ) -> None:
        self.render_mode = _check_render_mode(render_mode)
        self.task: CartPoleTask = task if task is not None else BalanceTask()
        self.physics = CartPolePhysics(constants if constants is not None else CartPoleConstants())
        self.observation_space = _observation_space(self.task)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.state: np.ndarray | None = None
        self.elapsed_steps = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.state = self.task.sample_starts(self.np_random, 1)[0]
        self.elapsed_steps = 0
        return self._observe(), {}

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (1,):
            raise ValueError(f"expected an action of shape (1,), got {action.shape}")
        if not np.isfinite(action).all():
            raise ValueError(f"non-finite action {action.tolist()}")
        states = self.state[None]  # a (1, 4) view: the physics updates self.state in place
        self.physics.step(states, _forces(action[None], self.physics.constants.max_force))
        self.elapsed_steps += 1
        reward, terminated = self.task.reward(states, self.elapsed_steps)
        truncated = self.elapsed_steps >= self.task.horizon
        return self._observe(), float(reward[0]), bool(terminated[0]), truncated, {}

    def _observe(self) -> np.ndarray:
        """The observation of the state (the camera's env draws a frame instead)."""
        assert self.state is not None
        return self.task.observe(self.state[None])[0]

    def render(self) -> np.ndarray | None:
        """An RGB frame (400, 600, 3), or None without render_mode 'rgb_array'."""
        if self.render_mode is None or self.state is None:
            return None
        return render_frame(self.state, self.physics.constants.half_length)


# ---------------------------------------------------------------------------------------------------- rendering

_VIEW_HALF_WIDTH = 3.0  # metres of track visible either side of the centre
_CART_HALF_WIDTH, _CART_HALF_HEIGHT = 0.25, 0.12
_POLE_HALF_THICKNESS = 0.03
_COLOURS = {
    "background": (255, 255, 255),
    "track": (60, 60, 60),
    "limit": (200, 60, 60),
    "cart": (40, 70, 120),
    "pole": (205, 145, 80),
    "axle": (120, 120, 200),
}


def render_frame(state: np.ndarray, half_length: float = 0.5, width: int = 600, height: int = 400) -> np.ndarray:
    """Draw one state (s, ṡ, θ, θ̇): track with the ±2.4 m limits, cart, pole and axle, as RGB uint8 (H, W, 3).

    Plain NumPy rasterisation: each shape is a mask over pixel centres in world coordinates (metres, the axle at
    height 0, 60% of the way down the picture).
    """
    s, theta = float(state[0]), float(state[2])
    scale = width / (2 * _VIEW_HALF_WIDTH)  # pixels per metre
    x = ((np.arange(width) + 0.5) - width / 2) / scale  # world x of each pixel column
    y = (0.6 * height - (np.arange(height)[:, None] + 0.5)) / scale  # world y of each pixel row
    dx = x - s
    along = dx * np.sin(theta) + y * np.cos(theta)  # coordinates in the pole's frame
    across = dx * np.cos(theta) - y * np.sin(theta)
    pixel = 1.0 / scale
    masks = {
        "track": np.abs(y + _CART_HALF_HEIGHT + pixel) <= pixel,  # a line two pixels thick under the cart
        "limit": (np.abs(np.abs(x) - POSITION_LIMIT) <= pixel) & (y >= -_CART_HALF_HEIGHT) & (y <= 0),  # ticks
        "cart": (np.abs(dx) <= _CART_HALF_WIDTH) & (np.abs(y) <= _CART_HALF_HEIGHT),
        "pole": (along >= 0) & (along <= 2 * half_length) & (np.abs(across) <= _POLE_HALF_THICKNESS),
        "axle": dx * dx + y * y <= (0.8 * _POLE_HALF_THICKNESS) ** 2,
    }
    frame = np.empty((height, width, 3), dtype=np.uint8)
    frame[:] = _COLOURS["background"]
    for name, mask in masks.items():  # later shapes are drawn over earlier ones
        frame[np.broadcast_to(mask, (height, width))] = _COLOURS[name]
    return frame


# ------------------------------------------------------------------------------------ what drrl knows of them

NEAR_OPTIMAL_RETURN = -50.0  # an LQR controller scores about −41


def balance_verdict(episode_returns, terminated) -> dict[str, bool]:
    """balanced: no evaluation episode left the bounds in its 200 steps; near-optimal: balanced and mean ≥ −50."""
    balanced = not bool(terminated.any())
    return {"balanced": balanced, "near_optimal": balanced and float(episode_returns.mean()) >= NEAR_OPTIMAL_RETURN}


def explain_balance(episode_returns, terminated) -> str:
    """What each verdict requires, beside how many episodes kept the pole up."""
    kept, episodes = int((~terminated).sum()), terminated.numel()
    return (
        f"({kept}/{episodes} episodes kept the pole up for all {BalanceTask.horizon} steps; balanced needs all "
        f"{episodes}, near-optimal needs balanced and a mean return ≥ {NEAR_OPTIMAL_RETURN:g})"
    )


def swing_up_verdict(episode_returns, terminated) -> dict[str, bool]:
    """solved: in every evaluation episode the cart stayed on the track and the return reached the threshold."""
    return {"solved": not bool(terminated.any()) and bool((episode_returns >= SWING_UP_SOLVED_RETURN).all())}


def explain_swing_up(episode_returns, terminated) -> str:
    high = int(((episode_returns >= SWING_UP_SOLVED_RETURN) & ~terminated).sum())
    return (
        f"({high}/{terminated.numel()} episodes kept the cart on the track and returned ≥ "
        f"{SWING_UP_SOLVED_RETURN:g} of at most {SwingUpTask.horizon}; solved needs all of them)"
    )


def failure_reward(steps, horizon: int = BalanceTask.horizon) -> np.ndarray:
    """5.8's reward for leaving the bounds at 1-based step t: −2·(T − t), known from the step alone."""
    return -2.0 * (horizon - np.asarray(steps, dtype=np.float64))


def swing_up_failure_reward(steps, horizon: int = SwingUpTask.horizon) -> np.ndarray:
    """The swing-up's reward for leaving the track at 1-based step t: −(T − t)."""
    return -1.0 * (horizon - np.asarray(steps, dtype=np.float64))


def balance_reward(observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The thesis's reward 5.8 on observations (s, ṡ, θ, θ̇), or (s, θ) when partially observed: 5.8 reads only s
    and θ. Imagined episodes use it on predicted observations."""
    states = np.zeros((len(observations), 4))
    states[:, 0::2] = observations[:, [0, -2 if observations.shape[1] == 4 else 1]]
    return BalanceTask().reward(states, steps)


def swing_up_reward(observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The swing-up task's reward on observations (s, ṡ, sin θ, cos θ, θ̇)."""
    s, s_dot, sin, cos, theta_dot = observations.astype(np.float64).T
    return SwingUpTask().reward(np.stack([s, s_dot, np.arctan2(sin, cos), theta_dot], 1), steps)


def balance_mirror(observations: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The balance tasks' mirror image, the track and the pole flipped left for right: every observed entry ((s, ṡ,
    θ, θ̇), or (s, θ) partially observed) and the force change sign; starts, rewards and ends do not change."""
    return -observations, -actions


_SWING_UP_FLIP = np.array([-1, -1, -1, 1, -1], dtype=np.float32)  # (s, ṡ, sin θ, cos θ, θ̇) flipped


def swing_up_mirror(observations: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The swing-up's mirror image, the track and the pole flipped left for right: s, ṡ, sin θ, θ̇ and the force
    change sign, cos θ does not; starts, rewards and ends do not change."""
    return observations * _SWING_UP_FLIP, -actions


def _register() -> None:
    """drrl's entries for the three cart-poles."""
    from drrl.envs.registry import EnvEntry, register

    balance: dict[str, Any] = {
        "verdict": balance_verdict,
        "explain": explain_balance,
        "reward": balance_reward,
        "end_reward": failure_reward,
        "mirror": balance_mirror,
    }
    for entry, task in (
        (EnvEntry("drrl/CartPole-v0", "cartpole", **balance), None),
        (
            EnvEntry(
                "drrl/CartPolePO-v0",
                "cartpole-po",
                **balance,  # only (s, θ) observed
            ),
            PartiallyObservedTask(),
        ),
        (
            EnvEntry(
                "drrl/CartPoleSwingUp-v0",
                "cartpole-swingup",
                swing_up_verdict,
                explain_swing_up,
                swing_up_reward,
                end_reward=swing_up_failure_reward,
                mirror=swing_up_mirror,
            ),
            SwingUpTask(),
        ),
    ):
        register(
            entry,
            "drrl.envs.cartpole:CartPoleEnv",
            "drrl.envs.cartpole:CartPoleVectorEnv",
            {} if task is None else {"task": task},
        )


_register()
