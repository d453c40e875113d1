"""Model-free training: PGPE (thesis 2.4, Algorithm 2) searching policy weights on a batched environment.

One generation: ask PGPE for P candidates, run them for E real episodes each in one batched rollout, tell PGPE their
mean returns, then measure the centre policy μ on separate evaluation episodes (counted apart, never as training).
Every generation appends a row to metrics.csv. Checkpoints, every ``checkpoint_every`` generations and whenever the
run stops (Ctrl-C, SIGTERM, an error), hold the state at the end of the last whole generation: the search (with its
random generator), the counters and the best centre. Episode seeds derive from the run seed and the generation, so
no environment state needs saving, and :func:`resume` continues to exactly the metrics of an uninterrupted run
(the wall_time column aside).
"""

from __future__ import annotations

import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from gymnasium.vector import VectorEnv
from tqdm import tqdm

from drrl.config import TrainConfig
from drrl.envs.batch import ActionMap, make_batch_env, observation_size, resolve_env_id
from drrl.envs.solved import VERDICTS, verdict_names
from drrl.policies import Policy, make_policy
from drrl.rollout import Backend, Evaluation, NonFiniteOutput, Workload, evaluate, make_backend
from drrl.runs import RunFolder
from drrl.search.pgpe import PGPE

TRAINING, MEASURING = 0, 1  # independent random streams for training and measuring episodes
CHECKPOINT_KIND = "model-free"
COUNTER_KEYS = ("generation", "real_episodes", "real_steps", "eval_episodes", "best_generation", "best_center_criteria")


@dataclass
class Counters:
    """What the run has spent so far. Real episodes and steps are training only; measuring is counted apart."""

    generation: int = 0
    real_episodes: int = 0
    real_steps: int = 0
    eval_episodes: int = 0
    rows: list[dict] = field(default_factory=list)  # one metrics row per generation
    best_center: torch.Tensor | None = None  # the best measured centre: most verdict criteria met, then highest return
    best_center_return: float = float("-inf")
    best_center_criteria: int = 0  # how many of the task's verdict criteria (balanced, ...) it met
    best_generation: int = 0
    wall_time: float = 0.0  # seconds since the run started, not counting the time it spent stopped


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


def better_center(met: dict[str, bool], center_return: float, best_criteria: int, best_return: float) -> bool:
    """Whether a measured centre beats the best one so far: more of the task's verdict criteria met (``met``),
    then a higher return. Both training loops keep their best centre by this rule; ``drrl eval`` runs it."""
    return (sum(met.values()), center_return) > (best_criteria, best_return)


@dataclass
class Setup:
    """The pieces of a run, built and checked before any training starts."""

    config: TrainConfig
    env_id: str
    backend: Backend  # evaluates the candidates: here, or on a Ray cluster
    eval_env: VectorEnv  # measures the centre policy, always here
    policy: Policy
    search: PGPE

    def close(self) -> None:
        self.backend.close()
        self.eval_env.close()


def prepare(config: TrainConfig, backend: str = "local", address: str | None = None,
            workers: int | None = None) -> Setup:
    """Build envs, policy, search and backend; bad names or unsupported spaces raise ValueError here, before any
    work."""
    env_id = resolve_env_id(config.env)
    eval_env = make_batch_env(env_id, config.eval_episodes)
    policy = build_policy(config, eval_env)
    workload = Workload(policy, env_id, config.popsize, config.episodes_per_candidate, config.max_steps)
    try:
        evaluator = make_backend(backend, workload, address=address, workers=workers)
    except BaseException:
        eval_env.close()
        raise
    return Setup(config, env_id, evaluator, eval_env, policy, build_search(config, policy))


def train(config: TrainConfig, out: Path | None = None, progress: bool = True, backend: str = "local",
          address: str | None = None, workers: int | None = None) -> Counters:
    """Spend ``config.budget`` real episodes on PGPE; write metrics, checkpoints and the learning curve to ``out``."""
    setup = prepare(config, backend, address, workers)
    return run(setup, None if out is None else RunFolder.create(out), progress)


def resume(path: Path, progress: bool = True, backend: str = "local", address: str | None = None,
           workers: int | None = None) -> Counters:
    """Continue the run in folder ``path`` from its checkpoint to the end of its budget."""
    folder = RunFolder(path)
    setup, counters = prepare_resume(folder, backend, address, workers)
    return run(setup, folder, progress, counters)


def prepare_resume(folder: RunFolder, backend: str = "local", address: str | None = None,
                   workers: int | None = None) -> tuple[Setup, Counters]:
    """The run in ``folder`` rebuilt at its checkpoint, its metrics.csv cut back to the checkpoint's generation.

    A folder that cannot be resumed exactly (a bad config or checkpoint, missing metrics) raises ValueError.
    """
    config = folder.read_config()
    if getattr(config, "model_based", None) is not None:
        raise ValueError(f"{folder.path} is a model-based run; --resume continues model-free runs only (so far)")
    checkpoint = folder.load_checkpoint()
    check_checkpoint(checkpoint)
    setup = prepare(config, backend, address, workers)
    try:
        counters = restore(setup, checkpoint)
        counters.rows = folder.truncate_metrics(counters.generation)
    except BaseException:
        setup.close()
        raise
    return setup, counters


def run(setup: Setup, folder: RunFolder | None = None, progress: bool = True,
        counters: Counters | None = None) -> Counters:
    """The generation loop of :func:`train` on prepared pieces, writing into ``folder`` if given.

    ``counters`` (from :func:`prepare_resume`) continue a run; without them the run starts at generation 0.
    """
    config = setup.config
    fresh = counters is None
    counters = Counters() if fresh else counters
    snapshot = checkpoint_state(setup.search, counters, setup.env_id, setup.policy)
    if folder is not None and fresh:
        folder.write_config(config)
        folder.save_checkpoint(snapshot)  # a run killed before its first checkpoint can still be resumed
    bar = tqdm(total=config.generations * config.episodes_per_generation, unit="ep", disable=not progress,
               initial=counters.generation * config.episodes_per_generation, desc="real episodes",
               dynamic_ncols=True)
    start = time.perf_counter() - counters.wall_time
    try:
        with _sigterm_as_interrupt():
            for generation in range(counters.generation + 1, config.generations + 1):
                row = run_generation(setup, counters, generation, start)
                if folder is not None:
                    folder.append_metrics(row)
                snapshot = checkpoint_state(setup.search, counters, setup.env_id, setup.policy)
                if folder is not None and generation % config.checkpoint_every == 0:
                    folder.save_checkpoint(snapshot)
                bar.update(config.episodes_per_generation)
                bar.set_postfix_str(f"gen {generation} | return mean {row['mean_return']:.1f} best "
                                    f"{row['best_return']:.1f} centre {row['center_return']:.1f}", refresh=False)
    finally:
        bar.close()
        setup.close()
        if folder is not None:
            folder.save_checkpoint(snapshot)  # the last whole generation's state, whatever stopped the run
            if counters.generation:
                folder.plot_learning_curve(f"{setup.env_id}, {config.policy} policy, {config.sampler} PGPE")
    return counters


def run_generation(setup: Setup, counters: Counters, generation: int, start: float) -> dict:
    """Ask, evaluate, tell and (when due) measure the centre; update ``counters`` and return the metrics row.

    ``start`` is the run's start on the ``time.perf_counter`` clock, for the wall_time column.
    """
    config, search = setup.config, setup.search
    candidates = search.ask()
    try:
        result = setup.backend.evaluate(candidates, derive_seed(config.seed, generation, TRAINING))
    except NonFiniteOutput as error:
        raise NonFiniteOutput(f"generation {generation}: {error}; stopped before updating the search") from None
    search.tell(result.returns.to(torch.float32))
    counters.generation = generation
    counters.real_episodes += result.episodes
    counters.real_steps += result.steps
    row = {"generation": generation, "real_episodes": counters.real_episodes,
           "real_steps": counters.real_steps, "mean_return": float(result.returns.mean()),
           "best_return": float(result.returns.max()), "center_return": float("nan"),
           "sigma_norm": float(search.sigma.norm())}
    if generation % config.eval_every == 0 or generation == config.generations:
        measured = measure(setup.policy, search.center, setup.eval_env, config,
                           derive_seed(config.seed, generation, MEASURING))
        counters.eval_episodes += measured.episodes
        row["center_return"] = float(measured.returns[0])
        verdict = VERDICTS.get(setup.env_id)
        met = {} if verdict is None else verdict(measured.episode_returns, measured.terminated)
        row.update({name: int(ok) for name, ok in met.items()})
        if better_center(met, row["center_return"], counters.best_center_criteria, counters.best_center_return):
            counters.best_center, counters.best_center_return = search.center, row["center_return"]
            counters.best_center_criteria, counters.best_generation = sum(met.values()), generation
    else:
        row.update(dict.fromkeys(verdict_names(setup.env_id), float("nan")))  # fixed metrics.csv columns
    counters.wall_time = time.perf_counter() - start
    row.update(eval_episodes=counters.eval_episodes, wall_time=round(counters.wall_time, 3))
    counters.rows.append(row)
    return row


@contextmanager
def _sigterm_as_interrupt():
    """While training, SIGTERM stops the run as Ctrl-C does (KeyboardInterrupt), so that both save a checkpoint."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def checkpoint_state(search: PGPE, counters: Counters, env_id: str, policy: Policy) -> dict:
    """The run's state between generations, for :meth:`RunFolder.save_checkpoint` and :func:`restore`."""
    best = search.center if counters.best_center is None else counters.best_center
    return {"kind": CHECKPOINT_KIND, "search": search.state_dict(), "center": search.center.detach().cpu(),
            "env_id": env_id, "best_center": best.detach().cpu(), "best_center_return": counters.best_center_return,
            "num_params": policy.num_params, "wall_time": counters.wall_time,
            **{key: getattr(counters, key) for key in COUNTER_KEYS}}


def check_checkpoint(checkpoint: dict) -> None:
    """Refuse a checkpoint this version cannot resume, saying what is wrong with it."""
    kind = checkpoint.get("kind")
    if kind != CHECKPOINT_KIND:
        raise ValueError(f"checkpoint is of kind {kind!r}; --resume continues {CHECKPOINT_KIND!r} runs only")
    missing = [key for key in ("search", "center", "best_center", "best_center_return", "env_id", "num_params",
                               "wall_time", *COUNTER_KEYS) if key not in checkpoint]
    if missing:
        raise ValueError(f"checkpoint lacks {', '.join(missing)}")
    for key in COUNTER_KEYS:
        value = checkpoint[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"checkpoint's {key} is {value!r}; it must be a whole number >= 0")
    for key in ("center", "best_center"):
        value = checkpoint[key]
        if not isinstance(value, torch.Tensor) or value.dim() != 1 or not bool(torch.isfinite(value).all()):
            raise ValueError(f"checkpoint's {key} must be a 1-D tensor of finite numbers")


def restore(setup: Setup, checkpoint: dict) -> Counters:
    """Load a checkpoint's search state into ``setup.search``; its counters (metrics rows not included)."""
    for key, expected in (("env_id", setup.env_id), ("num_params", setup.policy.num_params)):
        if checkpoint[key] != expected:
            raise ValueError(f"checkpoint is for {key} {checkpoint[key]!r} but the run's config gives {expected!r}")
    try:
        setup.search.load_state_dict(checkpoint["search"])
    except (KeyError, TypeError, AttributeError, RuntimeError) as error:
        raise ValueError(f"checkpoint's search state does not fit the run's config: {error}") from None
    if setup.search.generation != checkpoint["generation"]:
        raise ValueError(f"checkpoint's search state is at generation {setup.search.generation}, its counters at "
                         f"{checkpoint['generation']}")
    counters = Counters(**{key: checkpoint[key] for key in COUNTER_KEYS}, wall_time=float(checkpoint["wall_time"]),
                        best_center_return=float(checkpoint["best_center_return"]))
    counters.best_center = checkpoint["best_center"] if counters.best_generation else None
    return counters
