"""Model-based PGPE: the PGPE search pointed at a learned world model, with a data loop around it (thesis 2.3, 5.1).

One iteration:
    1. collect real episodes with the current centre policy μ and exploring candidates μ ± ε from the search;
    2. fit the world model(s) to all real episodes so far (``drrl.models.fit``; later fits start from the previous
       weights);
    3. run PGPE inside the model (an :class:`~drrl.models.imagined.ImaginedEnv`), from real start states, for at
       most ``model_based.generations`` generations, stopping early once the candidates' mean imagined return
       stops improving;
    4. measure μ on fresh real episodes (``eval_episodes``, 50 by default), counted as evaluation, never as
       training.
Iterations repeat until the budget of real training episodes is spent. Real steps and episodes are counted exactly
(by ``drrl.rollout.evaluate``); imagined steps and episodes are counted apart. The run folder holds the same files
as a model-free run (``drrl.runs.RunFolder``), one metrics row per iteration.

Divergence: a model whose loss turns non-finite, or imagined returns that do, stop the run with
:class:`ModelDiverged`; the model has its last good weights back and the checkpoint keeps it, the real episodes
and the search, so nothing is lost and no policy is trained on a broken model.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from tqdm import tqdm

from drrl.config import TrainConfig
from drrl.envs.batch import make_batch_env, resolve_env_id
from drrl.envs.solved import VERDICTS
from drrl.models.data import Episode, EpisodeBuffer, EpisodeRecorder
from drrl.models.fit import FitReport, FitSettings, fit
from drrl.models.imagined import KNOWN_REWARDS, ImaginedEnv, RewardFunction
from drrl.models.recurrent import WorldModel
from drrl.models.settings import MODEL_BASED_DEFAULTS, ModelBasedSettings
from drrl.policies import Policy
from drrl.rollout import Evaluation, NonFiniteOutput, evaluate
from drrl.runs import RunFolder
from drrl.search.pgpe import PGPE
from drrl.train import MEASURING, TRAINING, better_center, build_policy, build_search, derive_seed, measure

IMAGINING, FITTING = 2, 3  # random streams of imagined episodes and model fitting, apart from training and measuring


class ModelDiverged(RuntimeError):
    """The world model's loss, or the returns imagined in it, turned non-finite; the run stopped with the last good
    model, the data and the search kept."""


@dataclass
class ModelBasedSetup:
    """The pieces of a model-based run, built and checked before any work."""

    config: TrainConfig
    settings: ModelBasedSettings
    env_id: str
    eval_env: VectorEnv
    policy: Policy
    search: PGPE
    model: WorldModel
    known_reward: RewardFunction | None
    horizon: int


@dataclass
class ModelBasedResult:
    """What the run spent and measured (``rows``: one metrics row per iteration), and its final state."""

    model: WorldModel
    search: PGPE
    buffer: EpisodeBuffer = field(default_factory=EpisodeBuffer)
    rows: list[dict] = field(default_factory=list)
    iteration: int = 0
    real_episodes: int = 0
    real_steps: int = 0
    imagined_episodes: int = 0
    imagined_steps: int = 0
    eval_episodes: int = 0
    best_center: torch.Tensor | None = None
    best_center_return: float = float("-inf")
    best_center_criteria: int = 0
    best_iteration: int = 0

    def state_dict(self, env_id: str, policy: Policy) -> dict:
        """The run's state as tensors and plain values: what ``drrl eval`` reads (the keys of a model-free
        checkpoint, with iterations as generations), plus the world model(s) and the real episodes."""
        best = self.search.center if self.best_center is None else self.best_center
        return {"search": self.search.state_dict(), "center": self.search.center.detach().cpu(), "env_id": env_id,
                "best_center": best.detach().cpu(), "best_center_return": self.best_center_return,
                "best_center_criteria": self.best_center_criteria,
                "best_generation": self.best_iteration, "num_params": policy.num_params,
                "generation": self.iteration, "real_episodes": self.real_episodes, "real_steps": self.real_steps,
                "eval_episodes": self.eval_episodes, "imagined_episodes": self.imagined_episodes,
                "imagined_steps": self.imagined_steps, "model": dict(self.model.state_dict()),
                "buffer": self.buffer.state_dict() if len(self.buffer) else {}}


def model_based_config(model_based: dict | None = None, **settings) -> TrainConfig:
    """A validated model-based ``TrainConfig``: :data:`MODEL_BASED_DEFAULTS`, then ``settings``, with
    ``model_based`` the :class:`ModelBasedSettings` fields to change."""
    return TrainConfig.model_validate({**MODEL_BASED_DEFAULTS, **settings, "model_based": model_based or {}})


def prepare_model_based(config: TrainConfig) -> ModelBasedSetup:
    """Build and check everything; bad settings raise ValueError here, before any real episode is spent."""
    settings = config.model_based
    if settings is None:
        raise ValueError("config.model_based is not set: this is a model-free config (use drrl.train)")
    if config.budget < settings.initial_episodes:
        raise ValueError(f"budget: {config.budget} real episodes is fewer than model_based.initial_episodes "
                         f"({settings.initial_episodes}); raise the budget or lower initial_episodes")
    env_id = resolve_env_id(config.env)
    if settings.reward == "known" and env_id not in KNOWN_REWARDS:
        raise ValueError(f"model_based.reward: no closed-form reward is known for {env_id!r} (known for: "
                         f"{', '.join(KNOWN_REWARDS)}); use 'learned' or 'auto'")
    eval_env = make_batch_env(env_id, config.eval_episodes)
    try:
        policy = build_policy(config, eval_env)
        model = build_model(settings, eval_env, config.seed).to(config.device)
        horizon = config.max_steps or episode_horizon(env_id, eval_env)
    except ValueError:
        eval_env.close()
        raise
    known_reward = KNOWN_REWARDS.get(env_id) if settings.reward in ("auto", "known") else None
    return ModelBasedSetup(config, settings, env_id, eval_env, policy, build_search(config, policy), model,
                           known_reward, horizon)


def train_model_based(config: TrainConfig, out: Path | None = None, progress: bool = False) -> ModelBasedResult:
    """Spend ``config.budget`` real episodes on model-based PGPE, writing a run folder to ``out`` if given."""
    setup = prepare_model_based(config)
    return run_model_based(setup, None if out is None else RunFolder.create(out), progress)


def run_model_based(setup: ModelBasedSetup, folder: RunFolder | None = None, progress: bool = False
                    ) -> ModelBasedResult:
    """The iterations of :func:`train_model_based` on prepared pieces.

    Runs on one torch thread: the model's matrices are small (batches of a few hundred rows, widths of tens), so a
    second thread costs more in hand-offs than it gains, and leaves the other core to the machine.
    """
    config, settings = setup.config, setup.settings
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    result = ModelBasedResult(model=setup.model, search=setup.search)
    if folder is not None:
        folder.write_config(config)
    start = time.perf_counter()
    bar = tqdm(total=config.budget, unit="real ep", disable=not progress, desc=f"model-based {setup.env_id}",
               dynamic_ncols=True)
    try:
        for iteration, count in enumerate(iteration_sizes(config.budget, settings), start=1):
            row = run_iteration(setup, result, iteration, count)
            row["wall_time"] = round(time.perf_counter() - start, 3)
            result.rows.append(row)
            if folder is not None:
                folder.append_metrics(row)
            bar.update(count)
            bar.set_postfix(centre=f"{row['center_return']:.1f}", model=f"{row['imagined_center_return']:.1f}",
                            refresh=False)
    finally:
        torch.set_num_threads(threads)
        bar.close()
        setup.eval_env.close()
        if folder is not None:
            folder.save_checkpoint(result.state_dict(setup.env_id, setup.policy))
            if result.rows:
                folder.plot_learning_curve(f"{setup.env_id}, {config.policy} policy, model-based PGPE "
                                           f"({settings.model_kind} {'×'.join(map(str, settings.hidden))}, "
                                           f"K = {settings.ensemble_size})")
    return result


def run_iteration(setup: ModelBasedSetup, result: ModelBasedResult, iteration: int, count: int) -> dict:
    """Steps 1–4 of one iteration (module docstring); returns its metrics row."""
    config, settings, search, policy = setup.config, setup.settings, setup.search, setup.policy
    # 1. real episodes: the centre and explorers (only explorers before the model has informed μ)
    params = exploring_policies(search, count, with_center=iteration > 1)
    episodes, real = collect(policy, params, setup.env_id, derive_seed(config.seed, iteration, TRAINING),
                             config.max_steps)
    result.buffer.extend(episodes)
    result.iteration = iteration
    result.real_episodes += real.episodes
    result.real_steps += real.steps
    # 2. the model
    fit_start = time.perf_counter()
    fit_now = fitting_settings(settings.fit_settings(iteration == 1, setup.known_reward is None), result.buffer)
    reports = fit(setup.model, result.buffer, fit_now, seed=derive_seed(config.seed, iteration, FITTING))
    if any(report.stop == "diverged" for report in reports):
        raise ModelDiverged(f"iteration {iteration}: the world model's loss turned non-finite; stopped with its "
                            f"last good weights, the {len(result.buffer)} real episodes and the search kept")
    # 3. PGPE inside it, from real start states
    search_start = time.perf_counter()
    imagined = ImaginedEnv(setup.model, result.buffer.start_observations(), config.episodes_per_generation,
                           setup.eval_env.single_action_space, setup.horizon, setup.known_reward,
                           settings.disagreement_penalty)
    generations = search_in_model(setup, imagined, iteration, result)
    search_end = time.perf_counter()
    # 4. the centre, in the model and (counted apart) in reality
    in_model = evaluate(policy, search.center[None], imagined, imagined.num_envs,
                        seed=derive_seed(config.seed, iteration, IMAGINING))
    measured = measure(policy, search.center, setup.eval_env, config, derive_seed(config.seed, iteration, MEASURING))
    result.eval_episodes += measured.episodes
    center_return = float(measured.returns[0])
    verdict = VERDICTS.get(setup.env_id)
    met = {} if verdict is None else verdict(measured.episode_returns, measured.terminated)
    if better_center(met, center_return, result.best_center_criteria, result.best_center_return):
        result.best_center, result.best_center_return = search.center, center_return
        result.best_center_criteria, result.best_iteration = sum(met.values()), iteration
    return iteration_row(setup, result, real, reports, fit_now, in_model, measured, met, generations,
                         {"fit_time": search_start - fit_start, "search_time": search_end - search_start})


def iteration_row(setup: ModelBasedSetup, result: ModelBasedResult, real: Evaluation, reports: list[FitReport],
                  fit_now: FitSettings, in_model: Evaluation, measured: Evaluation, met: dict[str, bool],
                  generations: int, times: dict[str, float]) -> dict:
    """One metrics row; ``real_*`` and ``eval_episodes`` count real episodes, ``imagined_*`` the model's;
    ``met``: the task's verdict on the measured centre."""
    row = {"iteration": result.iteration, "real_episodes": result.real_episodes, "real_steps": result.real_steps,
           "imagined_episodes": result.imagined_episodes, "imagined_steps": result.imagined_steps,
           "generations": generations, "mean_return": float(real.returns.mean()),
           "center_return": float(measured.returns[0]), "imagined_center_return": float(in_model.returns[0]),
           "sigma_norm": float(setup.search.sigma.norm()), "overshoot": fit_now.overshoot,
           "model_loss": float(np.mean([report.valid_loss for report in reports])),
           "fit_updates": int(sum(report.updates for report in reports))}
    row.update({name: int(ok) for name, ok in met.items()})
    row["eval_episodes"] = result.eval_episodes
    row.update({name: round(seconds, 3) for name, seconds in times.items()})
    return row


def iteration_sizes(budget: int, settings: ModelBasedSettings) -> list[int]:
    """Real episodes collected by each iteration, within the budget (a remainder too small for an iteration is
    left unspent)."""
    later = (budget - settings.initial_episodes) // settings.episodes_per_iteration
    return [settings.initial_episodes] + [settings.episodes_per_iteration] * later


def build_model(settings: ModelBasedSettings, env: VectorEnv, seed: int) -> WorldModel:
    """The ensemble of world models ``settings`` describes, for ``env``'s observation and action sizes."""
    if not isinstance(env.single_action_space, spaces.Box):
        raise ValueError(f"model-based training needs a Box action space (the model reads actions as numbers), "
                         f"got {env.single_action_space}")
    observation_size = env.single_observation_space.shape[0]
    action_size = env.single_action_space.shape[0]
    with torch.random.fork_rng():  # the members' initial weights, without touching the global generator
        torch.manual_seed(seed)
        return WorldModel(observation_size, action_size, settings.hidden, settings.model_kind,
                          settings.future_inputs, members=settings.ensemble_size)


def episode_horizon(env_id: str, env: VectorEnv) -> int:
    """The steps after which the real env truncates an episode: its task's horizon or its registered limit."""
    task = getattr(env, "task", None)
    if task is not None:
        return int(task.horizon)
    limit = gymnasium.spec(env_id).max_episode_steps
    if limit is None:
        raise ValueError(f"{env_id} has no registered episode limit; set max_steps for imagined episodes")
    return int(limit)


def exploring_policies(search: PGPE, count: int, with_center: bool) -> torch.Tensor:
    """``count`` policies for real episodes: μ itself (if ``with_center``), then candidates μ ± ε drawn with the
    search's current σ."""
    candidates = search.ask()
    while len(candidates) < count:
        candidates = torch.cat([candidates, search.ask()])
    if with_center:
        return torch.cat([search.center[None], candidates[: count - 1]])
    return candidates[:count]


def collect(policy: Policy, params: torch.Tensor, env_id: str, seed: int, max_steps: int | None
            ) -> tuple[list[Episode], Evaluation]:
    """One recorded real episode per row of ``params``, and the exact steps and episodes spent.

    The env is seeded here so that every episode starts from its own state: ``evaluate``'s seeding gives every
    candidate the same start (common random numbers), which would make all the collected episodes start alike.
    """
    env = EpisodeRecorder(make_batch_env(env_id, len(params)))
    try:
        env.reset(seed=seed)
        evaluation = evaluate(policy, params, env, 1, seed=None, max_steps=max_steps)
        return env.episodes(), evaluation
    finally:
        env.close()


def fitting_settings(settings: FitSettings, buffer: EpisodeBuffer) -> FitSettings:
    """``settings`` with the overshooting horizon shortened while every real episode so far is shorter than one
    window (the first episodes of a falling pole can be); the iteration's row reports the horizon used."""
    longest = max(len(episode) for episode in buffer.episodes)
    if longest >= settings.unfold + settings.overshoot:
        return settings
    return dataclasses.replace(settings, overshoot=max(0, longest - settings.unfold))


def search_in_model(setup: ModelBasedSetup, imagined: ImaginedEnv, iteration: int, result: ModelBasedResult) -> int:
    """PGPE generations on imagined episodes, counted in ``result``; returns how many ran.

    Stops early (beyond the thesis, for speed) once the best mean imagined return of a generation's candidates has
    not improved for ``patience`` generations: the search has converged on this model, and more generations would
    only fit the model's errors.
    """
    config, settings, search = setup.config, setup.settings, setup.search
    best, since_best, generation = float("-inf"), 0, 0
    for generation in range(1, settings.generations + 1):
        candidates = search.ask()
        seed = derive_seed(config.seed, iteration * 1_000_000 + generation, IMAGINING)
        try:
            evaluation = evaluate(setup.policy, candidates, imagined, config.episodes_per_candidate, seed=seed,
                                  max_steps=config.max_steps)
        except NonFiniteOutput as error:
            raise ModelDiverged(f"iteration {iteration}, generation {generation}: the model imagined {error}; "
                                f"stopped before updating the search") from None
        returns = evaluation.returns
        search.tell(returns.to(torch.float32))
        result.imagined_episodes += evaluation.episodes
        result.imagined_steps += evaluation.steps
        mean = float(returns.mean())
        best, since_best = (mean, 0) if mean > best else (best, since_best + 1)
        if since_best >= settings.patience:
            break
    return generation
