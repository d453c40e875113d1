"""Model-free training by action-space policy gradients (thesis 2.1.4, 2.2.2): the methods PGPE is set against.

One step of the loop (``drrl.training.loop.run``) is one update: run the stochastic policy around θ for ``popsize`` ×
``episodes_per_candidate`` real episodes at once, every action drawn (``drrl.policy_gradient.episodes``), then step θ
and the actions' σ along the method's gradient (REINFORCE with a baseline, or eNAC). Everything else is the
model-free run's (``RealWorld``): real steps and episodes counted exactly by ``drrl.rollout.evaluate``, θ measured
on separate episodes within ``eval_share`` of the steps, the best centre kept, checkpoints every
``checkpoint_every`` updates, and an exact resume (the action noise comes from the method's generator, in its state;
episode starts from the run seed and the update).

The episodes run in this process, on the local backend's env: each step's observations, actions and rewards are
needed here, not only the returns a backend sends back.
"""

from __future__ import annotations

import dataclasses

from drrl.policies import Policy
from drrl.policy_gradient import PolicyGradient, collect
from drrl.rollout import Workload
from drrl.rollout.local import LocalBackend
from drrl.settings import TrainConfig
from drrl.streams import Stream, derive_seed
from drrl.training.loop import UNITS, Counters, Setup
from drrl.training.model_free import RealWorld, counted


class ActionSpace(RealWorld[PolicyGradient]):
    """Every update from real episodes that explore by action, stepped here on ``backend``'s env."""

    kind = "action-space"
    unit = UNITS[kind]
    training = "exploring episodes, mean (actions drawn around μ)"

    def __init__(self, config: TrainConfig, policy: Policy, backend: LocalBackend, workload: Workload):
        super().__init__(config, policy, backend, workload)
        self.local = backend  # the backend, typed as the local one whose env the episodes run on

    def step(self, setup: Setup[PolicyGradient], counters: Counters, iteration: int) -> dict:
        method = setup.search
        seed = derive_seed(self.config.seed, iteration, Stream.TRAINING)
        episodes = collect(method.explorer(), method.center, self.local.env, seed, self.config.max_steps)
        shift = self.settings.reward_shift
        method.improve(dataclasses.replace(episodes, rewards=episodes.rewards - shift * episodes.alive))
        result = episodes.evaluation
        return counted(counters, iteration, result) | {
            "best_return": float(result.episode_returns.max()),  # the best episode: all ran the same θ
            "sigma_norm": float(method.spread.norm()),
        }
