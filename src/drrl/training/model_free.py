"""Model-free training: the search on the real environment (thesis 2.4, Algorithm 2).

One step of the loop (``drrl.training.loop.run``) is one generation: ask for P candidates, run them for E real
episodes each in one batched rollout on the backend, tell the search their mean returns. The loop then measures
the centre policy μ on separate episodes, counted apart: every ``eval_every`` generations as long as measuring
takes at most ``eval_share`` of the run's env steps (a quarter by default: 50 measuring episodes after every
generation of 8 candidates cost six times the training itself), and after the last one. Checkpoints are taken
every ``checkpoint_every`` generations; episode seeds derive from the run seed and the generation, so no
environment state needs saving.

With ``observation_norm`` the search's policies act on observations normalised by the mean and std of all training
observations before this generation (``drrl.rollout.moments``; not in the thesis). The env runs them with the
normalisation folded into their first layer (``fold_input``), so backends, measuring
and ``drrl eval`` see plain policies, and the best centre is kept as the env ran it.

With ``restart_every`` (restarts, not in the thesis; as IPOP-CMA-ES restarts, Auger & Hansen 2005, without growing
the population) the run is a series of attempts of that many generations, each measured at its end: after an
attempt whose last centre does not meet every criterion of the task, the search starts again from a new random
centre and seed (``derive_seed(seed, attempt, RESTARTING)``), the observation statistics anew; after one whose centre
does, the run ends (its last centre, not its best: the best of many noisy measurements flatters a search that
stalled just short of the level). A search that settles in a local optimum (Pendulum-v1's spinning pendulum)
stays there however long it runs; an attempt from elsewhere may not. The first attempt is the run without restarts,
to the step.

With ``env_schedule`` (a curriculum, not in the thesis) each generation's training episodes run on the env made with
the schedule's value of its option for the budget spent so far, or for the steps its generations have earned (kept
in the checkpoint), so a resumed run continues it exactly. Measuring runs on the env as registered.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import torch

from drrl.envs.batch import RegisteredEnv
from drrl.policies import Policy
from drrl.rollout import Backend, Evaluation, NonFiniteOutput, Workload
from drrl.rollout.moments import Moments
from drrl.search.base import Search
from drrl.settings import ModelBasedSettings, ModelFreeSettings, TrainConfig
from drrl.streams import Stream, derive_seed
from drrl.training.loop import UNITS, Counters, L, Setup, World, attempt_ended, run_generation


class RealWorld(World[L]):
    """What the model-free worlds share, whatever their step improves (a ``Search``, or an action-space
    ``PolicyGradient``): every step on the real environment through ``backend``, measuring within ``eval_share``,
    checkpoints every ``checkpoint_every`` steps, and in the state the observation moments and a schedule's stage."""

    def __init__(self, config: TrainConfig, policy: Policy, backend: Backend, workload: Workload):
        world = config.world
        assert not isinstance(world, ModelBasedSettings)
        own = world if isinstance(world, ModelFreeSettings) else None  # an action-space run has none of its own
        self.schedule = None if own is None else own.env_schedule
        self.config, self.settings, self.policy, self.backend, self.workload = config, world, policy, backend, workload
        norm = own is not None and own.observation_norm
        self.moments = Moments.empty(1, policy.observation_size) if norm else None
        self.stage = 0  # steps an adaptive env_schedule has taken

    @property
    def iterations(self) -> int:
        return self.config.total_generations

    @property
    def real_budget(self) -> int:
        return self.config.demonstrations + self.config.total_generations * self.config.episodes_per_generation

    def measure_due(self, iteration: int, counters: Counters) -> bool:
        """After the last generation and an attempt's last; else every ``eval_every`` generations if measuring now
        keeps the steps spent measuring within ``eval_share`` of all, a measurement expected to cost as much as the
        earlier ones on average (before any: ``eval_episodes`` episodes as long as the training episodes so far)."""
        settings, episodes = self.settings, self.config.measuring.eval_episodes
        if iteration == self.iterations or attempt_ended(self.config, iteration):
            return True
        if iteration % settings.eval_every:
            return False
        measurements = counters.eval_episodes // episodes
        expected = (
            counters.eval_steps / measurements
            if measurements
            else episodes * counters.real_steps / counters.real_episodes
        )
        spent = counters.eval_steps + expected
        return spent <= settings.eval_share * (counters.real_steps + spent)

    def deployed(self, params: torch.Tensor) -> torch.Tensor:
        if self.moments is None:
            return params
        return self.policy.fold_input(params, *self.moments.mean_std())

    def state_dict(self) -> dict:
        state: dict = {} if self.moments is None else {"observation_moments": self.moments.state_dict()}
        return state | ({"schedule_stage": self.stage} if self.schedule is not None else {})

    def load_state_dict(self, state: dict) -> None:
        if self.moments is not None:
            self.moments = Moments.from_state_dict(state["observation_moments"])
        self.stage = int(state.get("schedule_stage", 0))

    def checkpoint_due(self, iteration: int) -> bool:
        return iteration % self.settings.checkpoint_every == 0

    def close(self) -> None:
        self.backend.close()


class ModelFree(RealWorld[Search]):
    """Every generation on the real environment, through ``backend`` (here, or on a Ray cluster); with
    ``restart_every``, ``new_search(attempt)`` is each later attempt's search."""

    kind = "model-free"
    unit = UNITS[kind]

    def __init__(
        self,
        config: TrainConfig,
        policy: Policy,
        backend: Backend,
        workload: Workload,
        new_search: Callable[[int], Search] | None = None,
    ):
        super().__init__(config, policy, backend, workload)
        assert isinstance(self.settings, ModelFreeSettings)
        self.restart_every = self.settings.restart_every
        if self.restart_every is not None and new_search is None:
            raise ValueError("restart_every needs new_search, to build each attempt's search")
        self.new_search = new_search

    def step(self, setup: Setup[Search], counters: Counters, iteration: int) -> dict:
        scheduled = self.follow_schedule(counters)
        attempt = self.attempt(iteration)
        if attempt and attempt_ended(self.config, iteration - 1):
            setup.search = self.restarted(setup.search, attempt)
        search = setup.search
        try:
            result, metrics = run_generation(
                search,
                self.backend,
                derive_seed(self.config.seed, iteration, Stream.TRAINING),
                self.deployed,
                self.settings.reward_shift,
            )
        except NonFiniteOutput as error:
            raise NonFiniteOutput(f"generation {iteration}: {error}; stopped before updating the search") from None
        if self.moments is not None and result.moments is not None:
            self.moments = self.moments.plus(result.moments)
        schedule = self.schedule
        if schedule is not None and schedule.advance_at is not None:
            self.stage += int(self.stage < schedule.steps and float(result.returns.median()) >= schedule.advance_at)
        row = counted(counters, iteration, result) | {"sigma_norm": metrics["sigma_norm"], **scheduled}
        return row | ({} if self.restart_every is None else {"attempt": attempt + 1})

    def attempt(self, iteration: int) -> int:
        """The attempt (0, 1, …) generation ``iteration`` belongs to; 0 without restarts."""
        every = self.restart_every
        return 0 if every is None else (iteration - 1) // every

    def restarted(self, search: Search, attempt: int) -> Search:
        """Attempt ``attempt``'s new search, counting its generations on from ``search``'s; observation statistics
        start again."""
        assert self.new_search is not None
        fresh = self.new_search(attempt)
        fresh.generation = search.generation
        if self.moments is not None:
            self.moments = Moments.empty(1, self.policy.observation_size)
        return fresh

    def follow_schedule(self, counters: Counters) -> dict[str, float]:
        """Point the backend at the env of this generation's scheduled option, if any; the option's value."""
        schedule = self.schedule
        if schedule is None:
            return {}
        value = schedule.value(counters.real_episodes / self.real_budget, self.stage)
        env = self.workload.env
        assert isinstance(env, RegisteredEnv)  # prepare gives a model-free run its registered env
        scheduled = RegisteredEnv(env.env_id, env.engine, ((schedule.option, value),))
        if self.workload.env != scheduled:
            self.workload = dataclasses.replace(self.workload, env=scheduled)
            self.backend.use(self.workload)
        return {schedule.option: value}


def counted(counters: Counters, iteration: int, result: Evaluation) -> dict:
    """Count a generation's real episodes and steps in ``counters``; the start of its metrics row."""
    counters.generations += 1
    counters.real_episodes += result.episodes
    counters.real_steps += result.steps
    return {
        "generation": iteration,
        "real_episodes": counters.real_episodes,
        "real_steps": counters.real_steps,
        "mean_return": float(result.returns.mean()),
        "best_return": float(result.returns.max()),
    }
