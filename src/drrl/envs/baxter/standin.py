"""A stand-in for the real Baxter (thesis 5.2.3, 6.2): drrl's model with its physics off the way a real robot's are.

A policy learned in simulation meets on the real robot link masses and joint friction unlike the model's, commands
that take effect a control period late, noisy joint sensors, and joints that follow a velocity command with a lag.
``StandIn`` is one such robot: its mass and damping errors are drawn once from its seed (a robot differs from its
model in a fixed way, not anew each episode), its delay, lag and sensor noise act at every step. The controller
compensates gravity for the nominal masses only, as the real one knows only the model. Rewards and failures follow
the true state; only the observations are noisy.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from drrl.envs.baxter.model import ARM


@dataclass(frozen=True)
class StandIn:
    """One robot that differs from the model: ``seed`` draws each moving link's mass and inertia scale from
    U(1 − ``mass_error``, 1 + ``mass_error``) and each joint's damping scale from U(1 − ``damping_error``, 1 +
    ``damping_error``); commands act ``delay`` control periods late and are followed with a first-order lag of time
    constant ``lag`` seconds; joint-angle readings get Gaussian noise of ``angle_noise`` rad, velocity readings of
    ``velocity_noise`` rad/s."""

    seed: int = 0
    mass_error: float = 0.2
    damping_error: float = 0.2
    delay: int = 1
    lag: float = 0.05
    angle_noise: float = 0.005
    velocity_noise: float = 0.05

    def __post_init__(self) -> None:
        if not (0 <= self.mass_error < 1 and 0 <= self.damping_error < 1):
            raise ValueError("mass_error and damping_error must be in [0, 1)")
        if self.delay < 0 or self.lag < 0 or self.angle_noise < 0 or self.velocity_noise < 0:
            raise ValueError("delay, lag, angle_noise and velocity_noise must be non-negative")

    def model(self, nominal, moving_arms: tuple[str, ...]):
        """A copy of the compiled ``nominal`` model with this robot's masses, inertias and damping."""
        rng = np.random.default_rng(self.seed)
        robot = copy.deepcopy(nominal)
        links = [robot.body(f"{side}_{joint.name}").id for side in moving_arms for joint in ARM]
        scale = rng.uniform(1 - self.mass_error, 1 + self.mass_error, len(links))
        robot.body_mass[links] *= scale
        robot.body_inertia[links] *= scale[:, None]
        robot.body_gravcomp[links] = 1 / scale  # the controller compensates the nominal mass
        dofs = [robot.joint(f"{side}_{joint.name}").dofadr[0] for side in moving_arms for joint in ARM]
        robot.dof_damping[dofs] *= rng.uniform(1 - self.damping_error, 1 + self.damping_error, len(dofs))
        return robot


class Actuation:
    """Commands on their way to the joints of ``num_envs`` robots: ``delay`` periods late, then followed with a lag."""

    def __init__(self, stand_in: StandIn, num_envs: int, num_joints: int, period: float) -> None:
        self._pending = np.zeros((stand_in.delay, num_envs, num_joints))
        self._applied = np.zeros((num_envs, num_joints))
        self._follow = 1.0 - np.exp(-period / stand_in.lag) if stand_in.lag > 0 else 1.0

    def restart(self, ids: np.ndarray) -> None:
        self._pending[:, ids] = 0.0
        self._applied[ids] = 0.0

    def __call__(self, commands: np.ndarray) -> np.ndarray:
        """The joint velocities that act in this period, given this period's ``commands``."""
        if len(self._pending):
            arriving = self._pending[0].copy()
            self._pending = np.roll(self._pending, -1, axis=0)
            self._pending[-1] = commands
        else:
            arriving = commands
        self._applied += self._follow * (arriving - self._applied)
        return self._applied.copy()
