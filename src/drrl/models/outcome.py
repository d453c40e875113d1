"""A task's reward and end learned as functions of the observation: what imagined episodes pay where drrl knows no
closed form (a Gymnasium env without one, a latent state of frames).

A small tanh network reads an observation o_{t+1} and predicts the reward r_{t+1} of the step into it and the
probability that the episode ends there; it is fitted to every real step so far (squared error on the standardised
reward, binary cross-entropy on the end, its ending steps weighted to count as much as all the others, since an
episode ends once and a miss costs a search every failure). Imagined episodes then call it as they call a task's
closed-form reward (``drrl.models.imagined``): an end where p > ½, and, where the task pays an ending step a reward
known from the step alone (``end_reward``, 5.8's failure −2·(T − t)), that reward there. The prediction is kept
within the range of the real rewards seen, so that a search cannot climb where the network extrapolates beyond
anything real.

Beyond the thesis, whose model predicts only the next observation: a reward and an end read off the observation
(as PlaNet and Dreamer read them off their latent state, and as 5.8 reads s and θ) are a plain regression and
classification on every real step, where a recurrent model's heads must learn a rare end (one step an episode) from
its hidden state: on the cart-pole those heads never predicted the failures, and a search on them never saw its
candidates fail.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
from torch import nn

from drrl.models.base import rebuilt, weights
from drrl.models.data import EpisodeBuffer

EndReward = Callable[[np.ndarray], np.ndarray]  # 1-based steps (N,) of ending steps -> their rewards (N,)


class OutcomeNetwork(nn.Module):
    """o (N, o) → (reward (N,), end logit (N,)): two tanh layers of ``hidden`` units on the standardised o."""

    observation_mean: torch.Tensor
    observation_scale: torch.Tensor
    reward_mean: torch.Tensor
    reward_scale: torch.Tensor

    def __init__(self, observation_size: int, hidden: int = 64):
        super().__init__()
        self.observation_size, self.hidden = observation_size, hidden
        self.net = nn.Sequential(
            nn.Linear(observation_size, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(), nn.Linear(hidden, 2)
        )
        self.register_buffer("observation_mean", torch.zeros(observation_size))
        self.register_buffer("observation_scale", torch.ones(observation_size))
        self.register_buffer("reward_mean", torch.zeros(()))
        self.register_buffer("reward_scale", torch.ones(()))

    def forward(self, observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(standardised reward, end logit), each (N,)."""
        out = self.net((observations - self.observation_mean) / self.observation_scale)
        return out[:, 0], out[:, 1]


@dataclass(frozen=True)
class LearnedOutcome:
    """A fitted ``OutcomeNetwork`` as a task's reward function (``RewardFunction``: next observations, steps →
    rewards, ends), small enough to send to a rollout worker."""

    settings: dict
    state: dict[str, torch.Tensor]
    reward_range: tuple[float, float]
    end_reward: EndReward | None = None

    def __call__(self, observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        network = self.network
        with torch.inference_mode():
            reward, logit = network(torch.as_tensor(observations, dtype=torch.float32))
            reward = reward * network.reward_scale + network.reward_mean
        rewards = reward.numpy().astype(np.float64).clip(*self.reward_range)
        ends = logit.numpy() > 0.0
        if self.end_reward is not None and ends.any():
            rewards = np.where(ends, self.end_reward(steps), rewards)
        return rewards, ends

    @cached_property
    def network(self) -> OutcomeNetwork:
        """The network, built from ``settings`` and ``state`` on the first call and kept."""
        return rebuilt(OutcomeNetwork, self.settings, self.state)


def fit_outcome(
    buffer: EpisodeBuffer,
    end_reward: EndReward | None = None,
    updates: int = 500,
    hidden: int = 64,
    seed: int = 0,
) -> LearnedOutcome:
    """An ``OutcomeNetwork`` fitted afresh to every step of ``buffer`` by Adam on minibatches of 256 steps. With
    ``end_reward`` the rewards of ending steps are the task's and are not fitted."""
    observations = np.concatenate([episode.observations[1:] for episode in buffer.episodes])
    rewards = np.concatenate([episode.rewards for episode in buffer.episodes]).astype(np.float32)
    ends = np.concatenate([episode.ends() for episode in buffer.episodes])
    fitted = ~ends.astype(bool) if end_reward is not None else np.ones(len(ends), dtype=bool)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        network = OutcomeNetwork(observations.shape[1], hidden)
    network.observation_mean.copy_(torch.as_tensor(observations.mean(0)))
    network.observation_scale.copy_(torch.as_tensor(np.maximum(observations.std(0), 1e-6)))
    paid = rewards[fitted] if fitted.any() else rewards
    network.reward_mean.fill_(float(paid.mean()))
    network.reward_scale.fill_(max(float(paid.std()), 1e-6))
    o, r, e, w = (torch.as_tensor(array) for array in (observations, rewards, ends, fitted.astype(np.float32)))
    target = (r - network.reward_mean) / network.reward_scale
    rare = torch.tensor(max((len(e) - float(e.sum())) / max(float(e.sum()), 1.0), 1.0))  # ends weigh all steps
    optimizer = torch.optim.Adam(network.parameters(), lr=3e-3)
    generator = torch.Generator().manual_seed(seed)
    for _ in range(updates):
        batch = torch.randint(len(o), (min(256, len(o)),), generator=generator)
        reward, logit = network(o[batch])
        loss = (w[batch] * (reward - target[batch]).square()).mean()
        loss = loss + nn.functional.binary_cross_entropy_with_logits(logit, e[batch], pos_weight=rare)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    low, high = float(paid.min()), float(paid.max())
    settings = {"observation_size": observations.shape[1], "hidden": hidden}
    return LearnedOutcome(settings, weights(network), (low, high), end_reward)
