"""The one training loop, for both worlds (thesis 2.4, Algorithm 2; 2.3 for the model-based world).

A search asks for candidates and is told their returns; it never knows whether they came from the real environment
or from a learned model. ``run_generation`` is that ask → evaluate on a backend → tell, and a ``World``
says what one step of the loop does with it:

* model-free (``drrl.training.model_free``): one generation on the real environment;
* model-based (``drrl.training.model_based``): collect real episodes, fit the world model, then generations inside it.

``run`` is the loop around any world: after each step it measures the centre policy on real episodes when due
(counted apart, never as training), keeps the best measured centre, appends a metrics row, and hands the row and,
when due, a checkpoint of the whole state to its subscribers (the run folder, the progress bar, TensorBoard). On
Ctrl-C, SIGTERM or an error the last whole step's state is checkpointed, and ``restore`` continues from it to
exactly the metrics of an uninterrupted run (wall time aside): every random number derives from the run seed and
the step, or lives in a saved state.
"""

from __future__ import annotations

import itertools
import re
import signal
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import torch
from gymnasium.vector import VectorEnv
from threadpoolctl import threadpool_limits

from drrl.envs.registry import EnvEntry
from drrl.policies import Policy
from drrl.rollout import Backend, Evaluation, evaluate
from drrl.search.base import Search
from drrl.settings import ModelFreeSettings, TrainConfig, short_repr
from drrl.streams import Stream, derive_seed

UNITS = {"model-free": "generation", "model-based": "iteration", "action-space": "generation"}  # World.unit by kind
MAX_COUNT = 2**53  # counts beyond it are not exact in metrics.csv's floats
COUNTS = (
    "iteration",
    "generations",
    "real_episodes",
    "real_steps",
    "imagined_episodes",
    "imagined_steps",
    "eval_episodes",
    "eval_steps",
    "best_iteration",
    "best_center_criteria",
)


def run_generation(
    search: Search,
    backend: Backend,
    seed: int,
    deploy: Callable[[torch.Tensor], torch.Tensor] | None = None,
    reward_shift: float = 0.0,
) -> tuple[Evaluation, dict[str, float]]:
    """One generation: ask the search for candidates, evaluate them on the backend (as ``deploy`` turns them into
    the env's policies, if given), tell the search their mean returns, ``reward_shift`` taken from every step's
    reward."""
    candidates = search.ask()
    evaluation = backend.evaluate(candidates if deploy is None else deploy(candidates), seed)
    return evaluation, search.tell(evaluation.returns_less(reward_shift).to(torch.float32))


@dataclass
class Counters:
    """What the run has spent so far. Real episodes and steps are training only; imagined ones (in a learned model)
    and measuring ones are counted apart."""

    iteration: int = 0  # steps of the loop: generations model-free, iterations model-based
    generations: int = 0  # generations of the search, in whichever world
    real_episodes: int = 0
    real_steps: int = 0
    imagined_episodes: int = 0
    imagined_steps: int = 0
    eval_episodes: int = 0
    eval_steps: int = 0
    rows: list[dict] = field(default_factory=list)  # one metrics row per step
    best_center: torch.Tensor | None = None  # the best measured centre: most verdict criteria met, then highest return
    best_center_return: float = float("-inf")
    best_center_criteria: int = 0  # how many of the task's verdict criteria (balanced, ...) it met
    best_iteration: int = 0
    wall_time: float = 0.0  # seconds since the run started, not counting the time it spent stopped


class Learner(Protocol):
    """What the loop needs of whatever improves the policy: a ``Search`` over parameters (PGPE, CMA-ES) or an
    action-space ``PolicyGradient``; a world is typed with the one it steps (``World[L]``)."""

    generation: int  # updates so far

    @property
    def center(self) -> torch.Tensor:
        """The policy's weights the loop measures and keeps, (n,): a copy."""

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...


L = TypeVar("L", bound=Learner)  # what a world's steps improve: its ``Setup``'s search


class World(ABC, Generic[L]):
    """Where the search's returns come from, and what one step of the loop does to its learner ``L``."""

    kind: str  # "model-free", "model-based" or "action-space", as checkpoints name it
    unit: str  # what a step is called in metrics.csv and messages: "generation" or "iteration"
    training: str = "candidates, mean (one episode each)"  # what a row's mean_return averages, for the plots

    @property
    @abstractmethod
    def iterations(self) -> int:
        """The steps a whole run takes."""

    @property
    @abstractmethod
    def real_budget(self) -> int:
        """The real training episodes a whole run spends (the budget, less a remainder too small for a step)."""

    @abstractmethod
    def step(self, setup: Setup[L], counters: Counters, iteration: int) -> dict:
        """Step ``iteration``: improve ``setup.search``, count what it spent in ``counters``; its metrics row."""

    def measure_due(self, iteration: int, counters: Counters) -> bool:
        """Whether the loop measures the centre after step ``iteration``, given what the run has spent."""
        return True

    def deployed(self, params: torch.Tensor) -> torch.Tensor:
        """The policies (P, n) that the env runs for the search's ``params``: the same, unless the world feeds the
        search's policies transformed observations."""
        return params

    def measured_on(self, env: VectorEnv) -> VectorEnv:
        """The env the loop measures the centre on, made of the real measuring ``env``: ``env`` itself, unless the
        world's policies read something else of it (the latent of frames, ``drrl.training.model_based``)."""
        return env

    def checkpoint_due(self, iteration: int) -> bool:
        return True

    def state_dict(self) -> dict:
        """The world's own state between steps (a model, its data), as copies."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``."""

    def title(self, setup: Setup) -> str:
        return f"{setup.entry.env_id}, {setup.config.policy} policy, {setup.config.search.name}"

    def close(self) -> None:
        """Release what the world holds (its backend)."""


@dataclass
class Setup(Generic[L]):
    """The pieces of a run, built and checked before any work: a search and the world that steps it."""

    config: TrainConfig
    entry: EnvEntry  # what drrl knows of the env: its id, verdict, closed-form reward
    policy: Policy
    search: L
    world: World[L]
    eval_env: VectorEnv  # measures the centre policy, always here
    spent: tuple[int, int] = (0, 0)  # real training episodes and steps spent before the first step (demonstrations)
    # what a long step is doing now, for the subscribers' ``doing`` (the loop points it at them while it runs)
    report: Callable[[str], None] = field(default=lambda doing: None, repr=False)

    def close(self) -> None:
        self.world.close()
        self.eval_env.close()


class Subscriber:
    """Told what the loop does (the run folder, the progress bar, TensorBoard: drrl.training.subscribers); each method
    does nothing here, a subscriber overrides those it needs."""

    def started(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        """Before the first step (``counters.iteration`` is 0 for a new run), with the state at the start."""

    def row(self, setup: Setup, counters: Counters, row: dict) -> None:
        """After every step, with its metrics row."""

    def checkpoint(self, snapshot: dict) -> None:
        """When a checkpoint is due, with the state after the step."""

    def ended(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        """When the run ends for any reason, with the last whole step's state."""

    def doing(self, setup: Setup, counters: Counters, doing: str) -> None:
        """While a step runs, what it is doing now (a model-based iteration: fitting, the search in the model)."""


def run(setup: Setup, subscribers: Sequence[Subscriber] = (), counters: Counters | None = None) -> Counters:
    """Step ``setup.world`` to the end of its budget, or until ``solved``; ``counters`` (from ``restore``) continue a
    run."""
    if counters is None:
        counters = Counters(real_episodes=setup.spent[0], real_steps=setup.spent[1])
    snapshot = checkpoint_state(setup, counters)
    for subscriber in subscribers:
        subscriber.started(setup, counters, snapshot)
    start = time.perf_counter() - counters.wall_time

    def report(doing: str) -> None:
        for subscriber in subscribers:
            subscriber.doing(setup, counters, doing)

    setup.report = report
    try:
        with sigterm_as_interrupt(), one_thread():
            for iteration in range(counters.iteration + 1, setup.world.iterations + 1):
                if solved(setup, counters):
                    break
                row = setup.world.step(setup, counters, iteration)
                row.update(measure_center(setup, counters, iteration))
                counters.iteration = iteration
                counters.wall_time = time.perf_counter() - start
                row.update(eval_episodes=counters.eval_episodes, wall_time=round(counters.wall_time, 3))
                counters.rows.append(row)
                for subscriber in subscribers:
                    subscriber.row(setup, counters, row)
                snapshot = checkpoint_state(setup, counters)
                if setup.world.checkpoint_due(iteration):
                    for subscriber in subscribers:
                        subscriber.checkpoint(snapshot)
    finally:
        setup.close()
        for subscriber in subscribers:  # the last whole step's state, whatever stopped the run
            subscriber.ended(setup, counters, snapshot)
    return counters


def solved(setup: Setup, counters: Counters) -> bool:
    """Whether a run is done before its budget: its last step's measured centre met every criterion of the task's
    verdict, and that step ended an attempt (``restart_every``) or the run stops there (``stop_when_solved``: real
    episodes are the currency, none is spent past a solved centre) once the last ``solved_in_a_row`` measured
    centres all met it."""
    criteria, config, measuring = setup.entry.criteria(), setup.config, setup.config.measuring

    def met(row: dict) -> bool:
        return all(row.get(name) == 1 for name in criteria)

    if not criteria or not counters.rows or not met(counters.rows[-1]):
        return False
    if attempt_ended(config, counters.iteration):
        return True
    if not measuring.stop_when_solved:
        return False
    measured = (row for row in reversed(counters.rows) if all(row.get(name) in (0, 1) for name in criteria))
    recent = list(itertools.islice(measured, measuring.solved_in_a_row))  # the newest measured centres
    return len(recent) == measuring.solved_in_a_row and all(map(met, recent))


def attempt_ended(config: TrainConfig, iteration: int) -> bool:
    """Whether step ``iteration`` is the last of an attempt of a run with ``restart_every``."""
    every = config.world.restart_every if isinstance(config.world, ModelFreeSettings) else None
    return every is not None and iteration > 0 and iteration % every == 0


def measure(policy: Policy, center: torch.Tensor, env: VectorEnv, max_steps: int | None, seed: int) -> Evaluation:
    """The centre policy μ over ``env.num_envs`` fresh episodes (under ``one_thread``, as ``run`` holds it, for the
    same numbers as in training)."""
    return evaluate(policy, center[None], env, env.num_envs, seed=seed, max_steps=max_steps)


def measure_center(setup: Setup, counters: Counters, iteration: int) -> dict:
    """When due, the centre's measured return and the task's verdict on it, and the best centre updated; else NaN
    in the same columns (metrics.csv keeps fixed columns)."""
    if not setup.world.measure_due(iteration, counters):
        return dict.fromkeys(("center_return", *setup.entry.criteria()), float("nan"))
    setup.report(f"measuring the centre on {setup.eval_env.num_envs} fresh episodes")
    center = deployed_center(setup)
    measured = measure(
        setup.policy,
        center,
        setup.eval_env,
        setup.config.max_steps,
        derive_seed(setup.config.seed, iteration, Stream.MEASURING),
    )
    counters.eval_episodes += measured.episodes
    counters.eval_steps += measured.steps
    center_return = float(measured.returns[0])
    met = setup.entry.judge(measured.episode_returns, measured.terminated)
    if better_center(met, center_return, counters.best_center_criteria, counters.best_center_return):
        counters.best_center, counters.best_center_return = center, center_return
        counters.best_center_criteria, counters.best_iteration = sum(met.values()), iteration
    return {"center_return": center_return, **{name: int(ok) for name, ok in met.items()}}


def deployed_center(setup: Setup) -> torch.Tensor:
    """The search's centre μ as the env runs it (``World.deployed``)."""
    return setup.world.deployed(setup.search.center[None])[0]


def better_center(met: dict[str, bool], center_return: float, best_criteria: int, best_return: float) -> bool:
    """Whether a measured centre beats the best one so far: more of the task's verdict criteria met (``met``),
    then a higher return. ``drrl eval`` runs the best one."""
    return (sum(met.values()), center_return) > (best_criteria, best_return)


@contextmanager
def one_thread():
    """torch and NumPy's BLAS on one thread while training and measuring: drrl's arrays are small, where a second
    thread costs more than it saves (Pendulum-v1's defaults on two cores: 81-88 s a run against 114-116 s), and a run's
    numbers then do not depend on the cores of the machine it ran on (CMA-ES's linear algebra on two BLAS threads
    gave the same seed other returns)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        torch.set_num_threads(threads)


@contextmanager
def sigterm_as_interrupt():
    """While training, SIGTERM stops the run as Ctrl-C does (KeyboardInterrupt), so that both save a checkpoint.
    Both handlers are installed here, so that neither depends on what a library imported earlier did with them; the
    command line installs them before it makes a run folder, so that no signal finds the folder half made."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = {how: signal.signal(how, interrupt) for how in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for how, handler in previous.items():
            signal.signal(how, handler)


# ------------------------------------------------------------------------------------------------ checkpoints


def checkpoint_state(setup: Setup, counters: Counters) -> dict:
    """The run's state between steps, for ``RunFolder.save_checkpoint`` and ``restore``."""
    search = setup.search
    best = search.center if counters.best_center is None else counters.best_center
    return {
        "kind": setup.world.kind,
        "unit": setup.world.unit,
        "config": setup.config.model_dump(mode="json"),
        "search": search.state_dict(),
        "center": deployed_center(setup).detach().cpu(),
        "env_id": setup.entry.env_id,
        "best_center": best.detach().cpu(),
        "best_center_return": counters.best_center_return,
        "num_params": setup.policy.num_params,
        "wall_time": counters.wall_time,
        **{key: getattr(counters, key) for key in COUNTS},
        "world": setup.world.state_dict(),
    }


def check_checkpoint(checkpoint: dict, kind: str) -> None:
    """Refuse a checkpoint this version cannot resume as a ``kind`` run, saying what is wrong with it."""
    if checkpoint.get("kind") != kind:
        raise ValueError(f"checkpoint is of kind {checkpoint.get('kind')!r} but the run's config is {kind!r}")
    if checkpoint.get("unit") != UNITS[kind]:
        raise ValueError(
            f"checkpoint's unit is {short_repr(checkpoint.get('unit'))}; a {kind} run's is {UNITS[kind]!r}"
        )
    missing = [
        key
        for key in (
            "search",
            "center",
            "best_center",
            "best_center_return",
            "env_id",
            "num_params",
            "wall_time",
            "world",
            *COUNTS,
        )
        if key not in checkpoint
    ]
    if missing:
        raise ValueError(f"checkpoint lacks {', '.join(missing)}")
    for key in COUNTS:
        value = checkpoint[key]
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_COUNT:
            raise ValueError(f"checkpoint's {key} is {short_repr(value)}; it must be a whole number from 0 to 2**53")
    for steps, episodes in (("real_steps", "real_episodes"), ("imagined_steps", "imagined_episodes")):
        if checkpoint[steps] < checkpoint[episodes]:
            raise ValueError(f"checkpoint's {steps} ({checkpoint[steps]}) is fewer than its {episodes}")
    if checkpoint["best_iteration"] > checkpoint["iteration"]:
        raise ValueError(
            f"checkpoint's best_iteration ({checkpoint['best_iteration']}) is past its iteration "
            f"({checkpoint['iteration']})"
        )
    wall_time, best = checkpoint["wall_time"], checkpoint["best_center_return"]
    if not _real(wall_time) or not 0 <= wall_time < float("inf"):
        raise ValueError(f"checkpoint's wall_time is {short_repr(wall_time)}; it must be a number of seconds >= 0")
    if (
        not _real(best)
        or best != best
        or best == float("inf")
        or (best == float("-inf")) != (checkpoint["best_iteration"] == 0)
    ):
        raise ValueError(
            f"checkpoint's best_center_return is {short_repr(best)}; it must be a finite return, or -inf before "
            f"any centre was measured"
        )
    _check_metrics_record(checkpoint.get("metrics"), checkpoint["iteration"])
    size = checkpoint["num_params"]
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"checkpoint's num_params is {size!r}; it must be a whole number >= 1")
    for key in ("center", "best_center"):
        value = checkpoint[key]
        if (
            not isinstance(value, torch.Tensor)
            or value.dtype != torch.float32
            or value.shape != (size,)
            or not bool(torch.isfinite(value).all())
        ):
            raise ValueError(f"checkpoint's {key} must be {size} finite float32 numbers (its num_params)")


def _real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_metrics_record(record, iteration: int) -> None:
    """The record of metrics rows a checkpoint holds (``RunFolder.save_checkpoint``): None, or its rows' count,
    bytes and SHA-256."""
    if record is None:
        return
    if (
        not isinstance(record, dict)
        or record.keys() != {"rows", "bytes", "sha256"}
        or record["rows"] != iteration
        or isinstance(record["bytes"], bool)
        or not isinstance(record["bytes"], int)
        or record["bytes"] < 0
        or not (isinstance(record["sha256"], str) and re.fullmatch("[0-9a-f]{64}", record["sha256"]))
    ):
        raise ValueError(f"checkpoint's record of its metrics rows is {short_repr(record)}; it is not one drrl writes")


def check_rows(counters: Counters) -> None:
    """Refuse metrics rows that do not end where the checkpoint's counters are (another run's, or edited)."""
    last = counters.rows[-1] if counters.rows else {}
    for key in ("real_episodes", "real_steps"):
        if last and last.get(key) != getattr(counters, key):
            raise ValueError(
                f"metrics.csv's last row has {key} {last.get(key)}, the checkpoint {getattr(counters, key)}: they "
                f"are not of the same run"
            )


def restore(setup: Setup, checkpoint: dict) -> Counters:
    """Load a checkpoint into ``setup``'s search and world; its counters (metrics rows not included)."""
    check_checkpoint(checkpoint, setup.world.kind)
    for key, expected in (("env_id", setup.entry.env_id), ("num_params", setup.policy.num_params)):
        if checkpoint[key] != expected:
            raise ValueError(f"checkpoint is for {key} {checkpoint[key]!r} but the run's config gives {expected!r}")
    world = setup.world
    for key, most in (("iteration", world.iterations), ("real_episodes", world.real_budget)):
        if checkpoint[key] > most:
            raise ValueError(f"checkpoint's {key} is {checkpoint[key]}, past the run's {most}")
    if checkpoint["best_center_criteria"] > len(setup.entry.criteria()):
        raise ValueError(
            f"checkpoint's best_center_criteria is {checkpoint['best_center_criteria']}; {setup.entry.env_id} has "
            f"{len(setup.entry.criteria())} criteria"
        )
    try:
        setup.search.load_state_dict(checkpoint["search"])
        setup.world.load_state_dict(checkpoint["world"])
    except (KeyError, TypeError, AttributeError, RuntimeError) as error:
        raise ValueError(f"checkpoint's state does not fit the run's config: {error}") from None
    if setup.search.generation != checkpoint["generations"]:
        raise ValueError(
            f"checkpoint's search state is at generation {setup.search.generation}, its counters at "
            f"{checkpoint['generations']}"
        )
    counters = Counters(
        **{key: checkpoint[key] for key in COUNTS},
        wall_time=float(checkpoint["wall_time"]),
        best_center_return=float(checkpoint["best_center_return"]),
    )
    counters.best_center = checkpoint["best_center"] if counters.best_iteration else None
    return counters
