"""The action-space policy gradient interface: improve a policy's weights θ from episodes that explore by action.

A policy gradient method (thesis 2.2.2) climbs J(θ) (2.11) by steps θ ← θ + α ∇J (2.12), estimating ∇J from
episodes in which every action was drawn from a stochastic policy around the deterministic one
(``drrl.policy_gradient.episodes``). ``PolicyGradient`` does once what every method shares: θ and the exploration's
log σ (learned with θ), their optimizer (the step rules of PGPE's centre, ``drrl.search.optimizers``), the random
generator that draws the actions, counting updates, and the state a checkpoint keeps. A method writes only its
``ascent``: the direction to step in from a batch of episodes.

``center`` is θ, as it is PGPE's μ, so the training loop measures, keeps and deploys either alike.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import torch

from drrl.policies.base import Policy
from drrl.policy_gradient.episodes import Episodes, Exploring
from drrl.search.optimizers import make_optimizer


class PolicyGradient(ABC):
    """θ (the policy's flat weights) and log σ (one per action output; none for Discrete actions), improved by
    ``improve`` from each batch of exploring episodes."""

    kind: str  # the method's name in configs and checkpoints

    def __init__(
        self,
        policy: Policy,
        center: torch.Tensor,
        *,
        discrete: bool,
        sigma_init: float,
        lr: float,
        optimizer: str = "adam",
        seed: int = 0,
    ):
        if not (math.isfinite(sigma_init) and sigma_init > 0):
            raise ValueError(f"sigma_init (the initial action std) must be a positive finite number, got {sigma_init}")
        self.policy, self.discrete, self.optimizer = policy, discrete, optimizer
        self.num_params = policy.num_params
        self.generation = 0
        self.theta = center.detach().to(torch.float32).clone().requires_grad_(True)
        outputs = 0 if discrete else policy.action_size
        self.log_std = torch.full((outputs,), math.log(sigma_init), device=self.theta.device, requires_grad=True)
        self._optimizer = make_optimizer(optimizer, [self.theta, self.log_std], lr)
        self.generator = torch.Generator(device=self.theta.device).manual_seed(int(seed))

    @property
    def center(self) -> torch.Tensor:
        """θ, shape (n,): a copy."""
        return self.theta.detach().clone()

    @property
    def spread(self) -> torch.Tensor:
        """The actions' standard deviations σ, one per action output (empty for Discrete actions): a copy."""
        return self.log_std.detach().exp()

    def explorer(self) -> Exploring:
        """The stochastic policy that collects the next batch of episodes."""
        return Exploring(self.policy, self.log_std, self.discrete, self.generator)

    @abstractmethod
    def ascent(self, episodes: Episodes) -> tuple[torch.Tensor, torch.Tensor]:
        """The direction (for θ, for log σ) in which to step, estimated from ``episodes`` of the current policy."""

    def improve(self, episodes: Episodes) -> dict[str, float]:
        """One step of 2.12 along ``ascent``; the update's metrics."""
        if episodes.alive.shape[1] < 2:
            raise ValueError(f"{self.kind} needs at least 2 episodes an update (its baseline comes from the others)")
        grad_theta, grad_log_std = self.ascent(episodes)
        if not (bool(torch.isfinite(grad_theta).all()) and bool(torch.isfinite(grad_log_std).all())):
            raise ValueError(f"{self.kind}'s gradient is not finite; the policy was not updated")
        old = self.center
        self.theta.grad, self.log_std.grad = -grad_theta, -grad_log_std  # torch optimizers minimise
        self._optimizer.step()
        self.theta.grad = self.log_std.grad = None
        self.generation += 1
        return {
            "center_step_norm": float((self.theta.detach() - old).norm()),
            "action_std": float(self.spread.mean()) if self.spread.numel() else float("nan"),
        }

    def state_dict(self) -> dict:
        """θ, log σ, the optimizer's and the generator's state, as tensors and plain values."""
        return {
            "kind": self.kind,
            "num_params": self.num_params,
            "generation": self.generation,
            "center": self.center,
            "log_std": self.log_std.detach().clone(),
            "rng_state": self.generator.get_state(),
            "optimizer_state": {
                index: {name: _copy(value) for name, value in values.items()}
                for index, values in self._optimizer.state_dict()["state"].items()
            },
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict`` saved by a method built with the same settings."""
        for key in ("kind", "num_params"):
            if state.get(key) != getattr(self, key):
                raise ValueError(f"state is for {key}={state.get(key)!r} but this method has {getattr(self, key)!r}")
        with torch.no_grad():
            self.theta.copy_(state["center"])
            self.log_std.copy_(state["log_std"])
        self.generator.set_state(state["rng_state"].cpu().to(torch.uint8))
        self._optimizer.load_state_dict(
            {"state": state["optimizer_state"], "param_groups": self._optimizer.state_dict()["param_groups"]}
        )
        self.generation = int(state["generation"])


def _copy(value):
    return value.clone() if isinstance(value, torch.Tensor) else value
