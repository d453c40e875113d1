"""Exploration in action space (thesis 2.2.2): a stochastic policy around a deterministic one, and its episodes.

PGPE perturbs a policy's parameters once an episode and runs it deterministically; the methods the thesis sets it
against perturb every action instead. Here the policy's raw outputs are the mean of a Gaussian with one standard
deviation per output, σ = exp(log σ) (Box actions), or the logits of a softmax (Discrete actions). The env
receives a sample as it receives a raw output (clipped to [-1, 1] and scaled onto the bounds; a one-hot's argmax),
so the policy measured between updates, the "centre", is the same network run on its mean or most likely action.

``collect`` runs the stochastic policy for B episodes through ``drrl.rollout.evaluate`` (so real steps and
episodes are counted exactly as for PGPE) and keeps what a gradient needs; ``log_probs`` replays the recorded
observations through the policy with gradients on, which for a recurrent policy rebuilds the same memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium.vector import VectorEnv, VectorWrapper

from drrl.policies.base import Policy
from drrl.rollout import Evaluation, evaluate


@dataclass(frozen=True)
class Episodes:
    """B episodes of T steps at most, step-major."""

    observations: torch.Tensor  # (T, B, o): what the policy saw before each action
    actions: torch.Tensor  # (T, B, a): the sampled raw actions (Box) or one-hot choices (Discrete)
    rewards: torch.Tensor  # (T, B) float64: 0 where the step lies past its episode's end
    alive: torch.Tensor  # (T, B) bool: the step belongs to its episode
    evaluation: Evaluation  # the episodes' returns and what they cost

    def rewards_to_go(self) -> torch.Tensor:
        """G_t = r_{t+1} + … + r_T for every step, (T, B): the return that follows each action."""
        return self.rewards.flip(0).cumsum(0).flip(0)


class Exploring(Policy):
    """``policy`` with sampled actions: its raw output plus Gaussian noise of std ``exp(log_std)``, or, if
    ``discrete``, a one-hot draw from the softmax of its outputs; keeps every observation and action it gives."""

    def __init__(self, policy: Policy, log_std: torch.Tensor, discrete: bool, generator: torch.Generator):
        super().__init__(policy.observation_size, policy.action_size, policy.shapes)
        self.policy, self.std, self.discrete, self.generator = policy, log_std.detach().exp(), discrete, generator
        self.seen: list[torch.Tensor] = []
        self.taken: list[torch.Tensor] = []

    def initial_state(self, population: int, batch: int, device: torch.device | str = "cpu") -> Any:
        return self.policy.initial_state(population, batch, device)

    def act(self, weights: list[torch.Tensor], obs: torch.Tensor, state: Any) -> tuple[torch.Tensor, Any]:
        raw, state = self.policy.act(weights, obs, state)
        if self.discrete:
            choice = torch.multinomial(raw.reshape(-1, raw.shape[-1]).softmax(-1), 1, generator=self.generator)
            action = torch.zeros_like(raw).view(-1, raw.shape[-1]).scatter_(1, choice, 1.0).view_as(raw)
        else:
            noise = torch.randn(raw.shape, generator=self.generator, device=raw.device)
            action = raw + self.std.to(raw.device) * noise
        self.seen.append(obs.clone())
        self.taken.append(action.clone())
        return action, state

    def initial_center(self, generator: torch.Generator | None = None) -> torch.Tensor:
        return self.policy.initial_center(generator)


class StepRewards(VectorWrapper):
    """Keeps every step's rewards and end flags of a ``VectorEnv`` while something steps it."""

    def __init__(self, env: VectorEnv):
        super().__init__(env)
        self.rewards: list[np.ndarray] = []
        self.ended: list[np.ndarray] = []

    def step(self, actions):
        observations, rewards, terminated, truncated, info = self.env.step(actions)
        self.rewards.append(np.asarray(rewards, dtype=np.float64))
        self.ended.append(np.asarray(terminated) | np.asarray(truncated))
        return observations, rewards, terminated, truncated, info


def collect(
    explorer: Exploring, params: torch.Tensor, env: VectorEnv, seed: int, max_steps: int | None = None
) -> Episodes:
    """``env.num_envs`` episodes of the exploring policy with weights ``params`` (n,), from starts drawn from
    ``seed``."""
    recorder = StepRewards(env)
    explorer.seen.clear()
    explorer.taken.clear()
    evaluation = evaluate(explorer, params[None], recorder, env.num_envs, seed=seed, max_steps=max_steps)
    ended = torch.as_tensor(np.stack(recorder.ended))
    alive = (ended.cumsum(0) - ended.long()) == 0  # a step is alive until the one that ends its episode, inclusive
    rewards = torch.as_tensor(np.stack(recorder.rewards)) * alive
    return Episodes(
        observations=torch.stack(explorer.seen)[:, 0],
        actions=torch.stack(explorer.taken)[:, 0],
        rewards=rewards,
        alive=alive,
        evaluation=evaluation,
    )


def log_probs(
    policy: Policy, params: torch.Tensor, log_std: torch.Tensor, episodes: Episodes, discrete: bool
) -> torch.Tensor:
    """log π(a_t | o_0..o_t) of every recorded action, (T, P, B/P), differentiable in ``params`` (P, n) and
    ``log_std`` (P, a): the B episodes are split among P copies of the policy, episode b going to copy b // (B/P)
    (P = B gives each episode its own copy, so one backward pass yields every episode's own gradient)."""
    steps, batch = episodes.alive.shape
    population = params.shape[0]
    observations = episodes.observations.to(params.device).view(steps, population, batch // population, -1)
    weights = policy.unflatten(params)
    state = policy.initial_state(population, batch // population, params.device)
    if state is None:  # feed-forward: every step in one product
        flat = observations.permute(1, 0, 2, 3).reshape(population, -1, observations.shape[-1])
        raw = policy.act(weights, flat, None)[0].view(population, steps, -1, policy.action_size).transpose(0, 1)
    else:
        outputs = []
        for observation in observations:
            output, state = policy.act(weights, observation, state)
            outputs.append(output)
        raw = torch.stack(outputs)
    actions = episodes.actions.to(params.device).view_as(raw)
    if discrete:
        return (raw.log_softmax(-1) * actions).sum(-1)
    std = log_std.exp()[None, :, None, :]
    return torch.distributions.Normal(raw, std).log_prob(actions).sum(-1)
