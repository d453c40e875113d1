"""Model-free training: PGPE (thesis 2.4, Algorithm 2) searching policy weights on a batched environment.

One generation: ask PGPE for P candidates, run them for E real episodes each in one batched rollout, tell PGPE their
mean returns, then measure the centre policy μ on separate evaluation episodes (counted apart, never as training).
Every generation appends a row to metrics.csv; checkpoints hold the search state and the centre policy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from gymnasium.vector import VectorEnv
from tqdm import tqdm

from drrl.config import TrainConfig
from drrl.envs.batch import ActionMap, make_batch_env, observation_size, resolve_env_id
from drrl.envs.solved import VERDICTS
from drrl.policies import Policy, make_policy
from drrl.rollout import Evaluation, evaluate
from drrl.runs import RunFolder
from drrl.search.pgpe import PGPE

TRAINING, MEASURING = 0, 1  # independent random streams for training and measuring episodes


class NonFiniteReturn(RuntimeError):
    """A candidate's return was NaN or infinite; the run stops with its folder and last checkpoint kept."""


@dataclass
class Counters:
    """What the run has spent so far. Real episodes and steps are training only; measuring is counted apart."""

    generation: int = 0
    real_episodes: int = 0
    real_steps: int = 0
    eval_episodes: int = 0
    rows: list[dict] = field(default_factory=list)  # one metrics row per generation
    best_center: torch.Tensor | None = None  # the centre policy with the highest measured return so far
    best_center_return: float = float("-inf")
    best_generation: int = 0


def derive_seed(seed: int, generation: int, stream: int) -> int:
    """An episode seed that depends only on the run seed, the generation and the stream."""
    return int(np.random.SeedSequence([seed, generation, stream]).generate_state(1)[0])


def build_policy(config: TrainConfig, env) -> Policy:
    return make_policy(config.policy, observation_size(env.single_observation_space),
                       ActionMap(env.single_action_space).size)


def build_search(config: TrainConfig, policy: Policy) -> PGPE:
    generator = torch.Generator().manual_seed(config.seed)
    return PGPE(policy.initial_center(generator).to(config.device), popsize=config.popsize, sampler=config.sampler,
                sigma_init=config.sigma_init, center_lr=config.center_lr, sigma_lr=config.sigma_lr,
                optimizer=config.optimizer, fitness_shaping=config.fitness_shaping,
                baseline_decay=config.baseline_decay, max_sigma_change=config.max_sigma_change, seed=config.seed)


def measure(policy: Policy, center: torch.Tensor, env, config: TrainConfig, seed: int) -> Evaluation:
    """The centre policy μ over ``env.num_envs`` fresh episodes."""
    return evaluate(policy, center[None], env, env.num_envs, seed=seed, max_steps=config.max_steps)


@dataclass
class Setup:
    """The pieces of a run, built and checked before any training starts."""

    config: TrainConfig
    env_id: str
    env: VectorEnv
    eval_env: VectorEnv
    policy: Policy
    search: PGPE


def prepare(config: TrainConfig) -> Setup:
    """Build envs, policy and search; bad names or unsupported spaces raise ValueError here, before any work."""
    env_id = resolve_env_id(config.env)
    env = make_batch_env(env_id, config.episodes_per_generation)
    eval_env = make_batch_env(env_id, config.eval_episodes)
    policy = build_policy(config, env)
    return Setup(config, env_id, env, eval_env, policy, build_search(config, policy))


def train(config: TrainConfig, out: Path | None = None, progress: bool = True) -> Counters:
    """Spend ``config.budget`` real episodes on PGPE; write metrics, checkpoints and the learning curve to ``out``."""
    setup = prepare(config)
    return run(setup, None if out is None else RunFolder.create(out), progress)


def run(setup: Setup, folder: RunFolder | None = None, progress: bool = True) -> Counters:
    """The generation loop of :func:`train` on prepared pieces, writing into ``folder`` if given."""
    config, env_id, env, eval_env, policy, search = (setup.config, setup.env_id, setup.env, setup.eval_env,
                                                     setup.policy, setup.search)
    verdict = VERDICTS.get(env_id)
    counters = Counters()
    if folder is not None:
        folder.write_config(config)
    start = time.perf_counter()
    bar = tqdm(total=config.generations * config.episodes_per_generation, unit="ep", disable=not progress,
               desc="real episodes", dynamic_ncols=True)
    try:
        for generation in range(1, config.generations + 1):
            candidates = search.ask()
            result = evaluate(policy, candidates, env, config.episodes_per_candidate,
                              seed=derive_seed(config.seed, generation, TRAINING), max_steps=config.max_steps)
            _check_finite(result.returns, generation)
            search.tell(result.returns.to(torch.float32))
            counters.generation = generation
            counters.real_episodes += result.episodes
            counters.real_steps += result.steps
            row = {"generation": generation, "real_episodes": counters.real_episodes,
                   "real_steps": counters.real_steps, "mean_return": float(result.returns.mean()),
                   "best_return": float(result.returns.max()), "center_return": float("nan"),
                   "sigma_norm": float(search.sigma.norm())}
            if generation % config.eval_every == 0 or generation == config.generations:
                measured = measure(policy, search.center, eval_env, config,
                                   derive_seed(config.seed, generation, MEASURING))
                counters.eval_episodes += measured.episodes
                row["center_return"] = float(measured.returns[0])
                if row["center_return"] > counters.best_center_return:
                    counters.best_center, counters.best_center_return = search.center, row["center_return"]
                    counters.best_generation = generation
                if verdict is not None:
                    row.update({name: int(ok) for name, ok in
                                verdict(measured.episode_returns, measured.terminated).items()})
            row.update(eval_episodes=counters.eval_episodes, wall_time=round(time.perf_counter() - start, 3))
            counters.rows.append(row)
            if folder is not None:
                folder.append_metrics(row)
                if generation % config.checkpoint_every == 0:
                    folder.save_checkpoint(checkpoint_state(search, counters, env_id, policy))
            bar.update(result.episodes)
            bar.set_postfix_str(f"gen {generation} | return mean {row['mean_return']:.1f} best "
                                f"{row['best_return']:.1f} centre {row['center_return']:.1f}", refresh=False)
    finally:
        bar.close()
        env.close()
        eval_env.close()
        if folder is not None:
            folder.save_checkpoint(checkpoint_state(search, counters, env_id, policy))
            if counters.generation:
                folder.plot_learning_curve(f"{env_id}, {config.policy} policy, {config.sampler} PGPE")
    return counters


def _check_finite(returns: torch.Tensor, generation: int) -> None:
    bad = torch.nonzero(~torch.isfinite(returns)).flatten().tolist()
    if bad:
        raise NonFiniteReturn(f"generation {generation}: candidate(s) {bad} returned non-finite returns "
                              f"{returns[bad].tolist()}; stopped before updating the search")


def checkpoint_state(search: PGPE, counters: Counters, env_id: str, policy: Policy) -> dict:
    best = search.center if counters.best_center is None else counters.best_center
    return {"search": search.state_dict(), "center": search.center.detach().cpu(), "env_id": env_id,
            "best_center": best.detach().cpu(), "best_center_return": counters.best_center_return,
            "best_generation": counters.best_generation,
            "num_params": policy.num_params, "generation": counters.generation,
            "real_episodes": counters.real_episodes, "real_steps": counters.real_steps,
            "eval_episodes": counters.eval_episodes}
