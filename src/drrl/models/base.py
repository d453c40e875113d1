"""The world-model interface: what imagination (``drrl.models.imagined``) and the model-based loop need of a model.

A model predicts, for a batch of environments, the next observation, the reward and whether the episode ends, from
the current observation and action and its own recurrent state; it may be an ensemble of K members, each predicting.
The recurrent models of thesis 3.3–3.5 (``drrl.models.recurrent.WorldModel``) are one kind; another kind is
one new module with a class of this shape (and its fitting).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch


@dataclass(frozen=True)
class Prediction:
    """What each of the K members predicts for each step t: o_{t+1}, r_{t+1} and P(episode ends at t+1)."""

    observations: torch.Tensor  # (K, ..., o)
    rewards: torch.Tensor  # (K, ...)
    ends: torch.Tensor  # (K, ...) probabilities


class LearnedModel(Protocol):
    """A learned model of an environment, stepped in batches (an ``nn.Module``). Every weight and buffer holds the
    members first (K, …), so that ``members_of`` can take some of them apart."""

    change_scale: torch.Tensor  # (K, o): each member's standard deviation of the per-step change, its error unit

    @property
    def device(self) -> torch.device:
        """Where the model's weights are."""

    def __len__(self) -> int:
        """K, the members of the ensemble (1 for a single model)."""

    def settings(self) -> dict:
        """Constructor arguments: ``type(model)(**model.settings())`` builds a model of the same shape."""

    def initial_state(self, batch: int) -> list[torch.Tensor]:
        """Fresh recurrent state for ``batch`` new episodes, every member's."""

    def step(
        self,
        observation: torch.Tensor,
        action: torch.Tensor,
        state: list[torch.Tensor],
        observed: bool | torch.Tensor = True,
    ) -> tuple[Prediction, list[torch.Tensor]]:
        """Every member's prediction of the next step (K, B, ·) for o_t (B, o) and a_t (B, a); the new state."""

    def unfold(
        self,
        observations: torch.Tensor,
        actions: torch.Tensor,
        observed_steps: int,
        previous_actions: torch.Tensor | None = None,
    ) -> Prediction:
        """Every member's predictions over windows (B, L, ·) of steps, the first ``observed_steps`` reading the data,
        the rest the model's own predictions; ``previous_actions`` (B, a) came before the windows."""

    def disagreement(self, prediction: Prediction) -> torch.Tensor:
        """(B,) how much the members disagree on a prediction; 0 for a single model."""

    def state_dict(self) -> dict[str, torch.Tensor]: ...

    def load_state_dict(self, state: dict[str, torch.Tensor]): ...


def weights(model: LearnedModel | torch.nn.Module) -> dict[str, torch.Tensor]:
    """A model's state (weights and buffers) as copies on the CPU, to keep or to send to another process."""
    return {name: tensor.detach().cpu().clone() for name, tensor in model.state_dict().items()}


def load_weights(module: LearnedModel | torch.nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Load a checkpoint's ``state`` into ``module``, on the module's device. Weights of other names or shapes (a run
    made by another version of drrl) are a ValueError that says so in one line."""
    device = next(iter(module.state_dict().values())).device
    try:
        module.load_state_dict({name: tensor.to(device) for name, tensor in state.items()})
    except RuntimeError:
        name = type(module).__name__
        raise ValueError(
            f"the checkpoint's {name} weights do not fit this version of drrl's {name} (a run made by another "
            "version?); train the run again"
        ) from None


def rebuilt(module_type: type, settings: dict, state: dict[str, torch.Tensor]):
    """``module_type(**settings)`` with the weights ``state``: the random initial weights it is made with, overwritten
    at once, leave no trace in torch's generator."""
    with torch.random.fork_rng(devices=[]):
        module = module_type(**settings)
    module.load_state_dict(state)
    return module


def members_of(model: LearnedModel, members: torch.Tensor) -> LearnedModel:
    """The ensemble of ``model``'s members ``members`` (indices) alone, each with its own weights: it predicts for
    them exactly what ``model`` does."""
    state = {name: tensor[members] for name, tensor in model.state_dict().items()}
    return rebuilt(type(model), {**model.settings(), "members": len(members)}, state).to(model.device)


def per_member(values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """Per-member ``values`` (K, *v) shaped to broadcast against ``like`` (K, …, *v)."""
    return values.reshape(values.shape[0], *[1] * (like.dim() - values.dim()), *values.shape[1:])


def spread(prediction: Prediction, change_scale: torch.Tensor) -> torch.Tensor:
    """(B,) the members' disagreement: the standard deviation over members of the predicted observation, in units of
    the data's per-step change ``change_scale`` (K, o), averaged over the observation's entries; 0 for one member."""
    if len(change_scale) == 1:
        return torch.zeros(prediction.observations.shape[1], device=prediction.observations.device)
    return (prediction.observations / change_scale.mean(0)).std(dim=0).mean(dim=-1)
