"""An ensemble of K world models, beyond the thesis, against the "curse of model uncertainty" it names (2.3).

The members share an architecture but start from different weights and hold out different episodes when fitted,
so they agree where the data pin the dynamics down and disagree where the data are thin. Imagination samples one
member per rollout (:class:`drrl.models.imagined.ImaginedEnv`), so a policy that exploits one member's error
meets the others, and it can penalise the disagreement. A single model is an ensemble of one.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from drrl.models.data import EpisodeBuffer
from drrl.models.fit import FitReport, FitSettings, fit
from drrl.models.recurrent import Prediction, WorldModel


class Ensemble(nn.Module):
    """K world models stepped side by side."""

    def __init__(self, make_member: Callable[[], WorldModel], size: int = 1):
        super().__init__()
        if size < 1:
            raise ValueError(f"an ensemble needs at least one member, got size {size}")
        self.members = nn.ModuleList(make_member() for _ in range(size))

    def __len__(self) -> int:
        return len(self.members)

    def fit(self, buffer: EpisodeBuffer, settings: FitSettings = FitSettings(), seed: int = 0) -> list[FitReport]:
        """Fit every member on ``buffer``, each with its own held-out episodes and minibatches."""
        return [fit(member, buffer, settings, seed=seed * len(self) + k) for k, member in enumerate(self.members)]

    def initial_state(self, batch: int) -> list[list[torch.Tensor]]:
        return [member.initial_state(batch) for member in self.members]

    def step(self, observation: torch.Tensor, action: torch.Tensor, state: list[list[torch.Tensor]],
             observed: bool | torch.Tensor = True) -> tuple[Prediction, list[list[torch.Tensor]]]:
        """Every member's prediction from the same inputs, stacked along a leading dimension K."""
        outputs = [member.step(observation, action, s, observed) for member, s in zip(self.members, state)]
        predictions = [prediction for prediction, _ in outputs]
        stacked = Prediction(observations=torch.stack([p.observations for p in predictions]),
                             rewards=torch.stack([p.rewards for p in predictions]),
                             ends=torch.stack([p.ends for p in predictions]))
        return stacked, [new_state for _, new_state in outputs]

    def disagreement(self, prediction: Prediction) -> torch.Tensor:
        """(B,) the members' spread: the standard deviation over members of the predicted observation, in units of
        the data's per-step change, averaged over the observation's entries; 0 for a single member."""
        if len(self) == 1:
            return torch.zeros(prediction.observations.shape[1], device=prediction.observations.device)
        scale = self.members[0].change_scale
        return (prediction.observations / scale).std(dim=0).mean(dim=-1)
