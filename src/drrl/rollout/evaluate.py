"""Evaluate P candidates × E episodes in one batched rollout, counting real steps and episodes exactly.

The env must hold P·E sub-environments: candidate p's episode e runs in slot p·E + e. Every slot runs one episode;
a slot whose episode has ended is masked (its later rewards and steps are not counted) while the others go on.
A NaN or infinite observation, reward or return of a running episode stops the rollout with
``NonFiniteOutput``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import torch
from gymnasium.vector import VectorEnv

from drrl.envs.batch import ActionMap
from drrl.policies.base import Policy
from drrl.rollout.moments import Moments


class NonFiniteOutput(RuntimeError):
    """An environment returned a NaN or infinite observation or reward during a running episode."""


@dataclass(frozen=True)
class Evaluation:
    """Returns of one batched rollout and what it cost."""

    episode_returns: torch.Tensor  # (P, E)
    terminated: torch.Tensor  # (P, E) bool: the episode ended by failure or success, not by a time limit
    episode_steps: torch.Tensor  # (P, E) int64: environment steps each episode took while it ran
    moments: Moments | None = None  # of the observations acted on in running episodes, a row per slot, if asked

    @property
    def returns(self) -> torch.Tensor:
        """Each candidate's mean return over its E episodes, shape (P,)."""
        return self.episode_returns.mean(dim=1)

    @property
    def steps(self) -> int:
        """Environment steps taken by running episodes, summed over slots."""
        return int(self.episode_steps.sum())

    @property
    def episodes(self) -> int:
        """Episodes run: P·E."""
        return self.episode_returns.numel()

    def returns_less(self, per_step: float) -> torch.Tensor:
        """Each candidate's mean return with ``per_step`` taken from the reward of every step its episodes took,
        shape (P,)."""
        return (self.episode_returns - per_step * self.episode_steps).mean(dim=1)

    @staticmethod
    def concat(parts: list[Evaluation]) -> Evaluation:
        """One evaluation of all candidates from evaluations of consecutive chunks of them."""
        moments = [part.moments for part in parts]
        return Evaluation(
            episode_returns=torch.cat([part.episode_returns for part in parts]),
            terminated=torch.cat([part.terminated for part in parts]),
            episode_steps=torch.cat([part.episode_steps for part in parts]),
            moments=None if None in moments else Moments.concat(cast(list[Moments], moments)),
        )


def episode_seeds(seed: int, population: int, episodes: int) -> list[int]:
    """Reset seeds for the P·E slots from one seed.

    Episode e of every candidate starts from the same state (common random numbers): paired candidates μ ± ε are
    then compared on equal starts, which removes the start's noise from r⁺ − r⁻ in 2.31.
    """
    per_episode = np.random.default_rng(seed).integers(2**63, size=episodes)
    return np.tile(per_episode, population).tolist()


@torch.inference_mode()
def evaluate(
    policy: Policy,
    params: torch.Tensor,
    env: VectorEnv,
    episodes: int = 1,
    seed: int | None = None,
    max_steps: int | None = None,
    moments: bool = False,
) -> Evaluation:
    """Run each of the P candidates in ``params`` (P, n) for ``episodes`` episodes on ``env`` at once.

    ``max_steps`` cuts episodes that have not ended by then (for envs without a time limit of their own);
    ``moments`` sums the observations acted on (``Moments``).
    """
    population = params.shape[0]
    slots = population * episodes
    if env.num_envs != slots:
        raise ValueError(
            f"env has {env.num_envs} sub-environments; {population} candidates × {episodes} episodes need {slots}"
        )
    action_map = ActionMap(env.single_action_space)
    weights = policy.unflatten(params)
    state = policy.initial_state(population, episodes, params.device)
    seeds = None if seed is None else episode_seeds(seed, population, episodes)
    obs, _ = env.reset(seed=seeds)  # type: ignore[arg-type]  # drrl's batches take a seed per sub-env
    _check_finite("observation", obs, np.ones(slots, dtype=bool), 0, episodes)
    returns = np.zeros(slots)
    running = np.ones(slots, dtype=bool)
    terminated_slots = np.zeros(slots, dtype=bool)
    steps = np.zeros(slots, dtype=np.int64)
    t = 0
    seen = Moments.empty(slots, policy.observation_size) if moments else None
    while running.any() and (max_steps is None or t < max_steps):
        if seen is not None:
            seen.add(obs, running)
        obs_t = torch.as_tensor(obs, dtype=torch.float32, device=params.device).view(population, episodes, -1)
        raw, state = policy.act(weights, obs_t, state)
        obs, reward, terminated, truncated, _ = env.step(action_map(raw.reshape(slots, -1)))
        _check_finite("reward", reward, running, t + 1, episodes)
        _check_finite("observation", obs, running, t + 1, episodes)
        steps += running
        np.add(returns, reward, out=returns, where=running)
        terminated_slots |= running & terminated
        running &= ~(terminated | truncated)
        t += 1
    _check_finite("return", returns, np.ones(slots, dtype=bool), t, episodes)  # finite rewards can still overflow
    episode_returns = torch.as_tensor(returns, dtype=torch.float64).view(population, episodes)
    return Evaluation(
        episode_returns=episode_returns,
        terminated=torch.as_tensor(terminated_slots).view(population, episodes),
        episode_steps=torch.as_tensor(steps).view(population, episodes),
        moments=seen,
    )


def _check_finite(what: str, values: np.ndarray, running: np.ndarray, step: int, episodes: int) -> None:
    """Raise ``NonFiniteOutput`` naming the first running slot whose ``values`` (per slot) are not finite."""
    if np.isfinite(values).all():
        return
    finite = np.isfinite(np.asarray(values).reshape(len(running), -1)).all(axis=1)
    bad = np.flatnonzero(running & ~finite)
    if bad.size:
        slot = int(bad[0])
        raise NonFiniteOutput(
            f"the environment returned a non-finite {what} {np.asarray(values)[slot]} at step "
            f"{step} of candidate {slot // episodes}'s episode {slot % episodes} "
            f"({bad.size} slot(s) affected)"
        )
