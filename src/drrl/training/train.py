"""Training runs: build a run's pieces from its config, then run the one loop (``drrl.training.loop``) in its world.

``config.model_based`` unset: model-free training (``ModelFree``), every generation on the
real environment. Set: model-based training (``ModelBased``), generations inside a world
model fitted to real episodes. An action-space policy gradient ("reinforce", "enac"): model-free
updates from episodes that explore by action (``ActionSpace``). All run through the same loop, checkpoints and
subscribers (the action-space ones on the local backend), and all resume from their checkpoint to exactly the
metrics of an uninterrupted run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv

from drrl.envs.batch import ActionMap, RegisteredEnv, choose_engine, is_frames, make_batch_env, observation_size
from drrl.envs.registry import EnvEntry, is_own, lookup
from drrl.models.base import load_weights
from drrl.policies import Policy, make_policy
from drrl.policy_gradient import make_policy_gradient
from drrl.rollout import Workload, make_backend
from drrl.rollout.local import LocalBackend
from drrl.runs import RunFolder
from drrl.search import make_search
from drrl.search.base import Search
from drrl.settings import (
    ActionSpaceSettings,
    Demonstrations,
    ModelBasedSettings,
    ModelFreeSettings,
    PGPESettings,
    PolicyGradientSettings,
    TrainConfig,
    short_repr,
)
from drrl.streams import Stream, derive_seed
from drrl.training.action_space import ActionSpace
from drrl.training.cloning import check_clonable, cloned
from drrl.training.loop import (
    Counters,
    Learner,
    Setup,
    Subscriber,
    World,
    check_checkpoint,
    check_rows,
    restore,
    run,
)
from drrl.training.model_based import ModelBased, build_model, frame_autoencoder, reading
from drrl.training.model_free import ModelFree
from drrl.training.subscribers import ModelGuard, ProgressBar, RunFolderWriter, TensorBoardLogger


def build_policy(config: TrainConfig, env) -> Policy:
    return make_policy(
        config.policy, policy_inputs(config, env.single_observation_space), ActionMap(env.single_action_space).size
    )


def policy_inputs(config: TrainConfig, space: spaces.Space) -> int:
    """What the policy reads of an observation of ``space``: all of it, or for frames the latent state a
    model-based run encodes them to (``drrl.models.frames``), and the world model's memory where a model-based run
    asks for it (``drrl.models.remembering``); a model-free run on frames is refused."""
    memory = config.model_based.memory_size() if config.model_based else 0
    if not is_frames(space):
        return observation_size(space) + memory
    if config.model_based is None:
        raise ValueError(
            f"{config.env} observes frames {space.shape}, which a policy reads through the latent state a "
            f"model-based run learns: add --model-based (or a [model_based] table)"
        )
    frames = (space.shape or (1,))[0]
    return frames * config.model_based.latent_size + memory  # ``FrameAutoencoder.features``


def build_search(config: TrainConfig, policy: Policy, discrete: bool, center: torch.Tensor | None = None) -> Learner:
    """The search over the policy's parameters, or the action-space policy gradient, that ``config`` names, from
    ``center`` or the policy's own initial centre."""
    center = initial_center(config, policy, center)
    search = config.search
    if isinstance(search, PolicyGradientSettings):
        return make_policy_gradient(
            search.name,
            policy,
            center,
            discrete=discrete,
            sigma_init=search.sigma_init,
            lr=search.center_lr,
            optimizer=search.optimizer,
            seed=config.seed,
        )
    return parameter_search(config, center)


def initial_center(config: TrainConfig, policy: Policy, center: torch.Tensor | None = None) -> torch.Tensor:
    """``center``, or the policy's own initial centre drawn from the run seed, on the run's device."""
    if center is None:
        center = policy.initial_center(torch.Generator().manual_seed(config.seed))
    return center.to(config.device)


def parameter_search(config: TrainConfig, center: torch.Tensor) -> Search:
    """The search over the policy's parameters that ``config`` names (PGPE, CMA-ES), from ``center``."""
    search = config.search
    assert not isinstance(search, PolicyGradientSettings), "an action-space policy gradient is not a parameter search"
    apart = {"name", "popsize", "sigma_init", "episodes_per_candidate"}  # given to make_search, or not the search's
    pgpe = search.model_dump(exclude=apart) if isinstance(search, PGPESettings) else {}
    return make_search(
        search.name, center, popsize=search.popsize, sigma_init=search.sigma_init, seed=config.seed, **pgpe
    )


def restarted_search(config: TrainConfig, policy: Policy, attempt: int) -> Search:
    """Attempt ``attempt``'s search of a run with ``restart_every``: the run's, from the policy's initial centre and
    the search's seed both drawn anew."""
    restarted = config.model_copy(update={"seed": derive_seed(config.seed, attempt, Stream.RESTARTING)})
    return parameter_search(restarted, initial_center(restarted, policy))


def memory_needed(config: TrainConfig, policy: Policy) -> int:
    """A lower bound on the bytes a run holds at once: the candidates' weights and the search's vectors, a
    rollout's observation and action arrays (a few temporaries each), and a world model's weights and the
    imagined episodes' states and a fitting step's batch. The environments' own state comes on top."""
    slots = config.episodes_per_generation
    needed = 4 * policy.num_params * (config.search.popsize + 8)
    needed += 8 * 8 * (slots + config.measuring.eval_episodes) * (policy.observation_size + policy.action_size)
    if config.model_based is not None:
        model, widths = config.model_based, config.model_based.hidden
        inputs = policy.observation_size + policy.action_size
        weights = sum(
            (fan_in + width) * 4 * width for fan_in, width in zip((inputs, *widths[:-1]), widths, strict=True)
        )
        needed += 4 * model.ensemble_size * (4 * weights + 2 * slots * sum(widths))  # Adam's moments, states
        window = (model.unfold + model.overshoot) * (inputs + 4 * sum(widths))  # a window's activations (LSTM: 4)
        needed += 4 * model.ensemble_size * model.fit_batch_size * window * 2  # a gradient step's, and their grads
    return needed


def check_memory(config: TrainConfig, policy: Policy) -> None:
    """Refuse, before any work, a run that could not fit in the memory free now."""
    needed = memory_needed(config, policy)
    free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else None
    if free is not None and needed > free:
        smaller = "policy, popsize, model or fit_batch_size" if config.model_based else "policy, popsize or model"
        raise ValueError(
            f"this run needs at least {needed / 2**30:.1f} GiB ({config.search.popsize} candidates of a "
            f"{policy.num_params:,}-weight {config.policy} policy, their episodes"
            f"{', the world model and its fitting batch' if config.model_based else ''}), more than the "
            f"{free / 2**30:.1f} GiB free; use a smaller {smaller}"
        )


def resolved(config: TrainConfig, env_id: str) -> TrainConfig:
    """``config`` with the settings left to drrl decided for ``env_id``: the engine, and a model-free run's
    observation normalisation (on for envs that are not drrl's own, whose observations can be of any scale, unless
    the run starts from another policy)."""
    world = config.world
    scheduled = isinstance(world, ModelFreeSettings) and world.env_schedule is not None
    update: dict = {"engine": choose_engine(env_id, config.engine, with_options=scheduled)}
    if isinstance(world, ModelFreeSettings) and world.observation_norm is None:
        norm = not is_own(env_id) and world.start is None
        update["world"] = world.model_copy(update={"observation_norm": norm})
    return config.model_copy(update=update)


def prepare(
    config: TrainConfig,
    backend: str = "local",
    address: str | None = None,
    workers: int | None = None,
    resuming: bool = False,
    progress: bool = False,
) -> Setup:
    """Build envs, policy, search, world and backend; bad names, settings or unsupported spaces raise ValueError
    here, before any work. A new run (not ``resuming``) with ``config.start_from`` starts from that run's policy and
    world model (``transferred``), one with ``config.demonstrations`` from the clone of the env's demonstrator
    (``demonstrated_start``; ``progress`` shows its episodes)."""
    entry = lookup(config.env)
    settings = config.world
    restarts = isinstance(settings, ModelFreeSettings) and settings.restart_every is not None
    for name, given in (("stop_when_solved", config.measuring.stop_when_solved), ("restart_every", restarts)):
        if given and not entry.criteria():
            raise ValueError(f"{name}: {entry.env_id} has no verdict (no solved level) to stop at")
    if isinstance(settings, ActionSpaceSettings) and backend != "local":
        raise ValueError(
            f"search {settings.search.name} runs its episodes here; use the local backend (--backend local)"
        )
    config = resolved(config, entry.env_id)
    schedule = config.world.env_schedule if isinstance(config.world, ModelFreeSettings) else None
    options = {} if schedule is None else {schedule.option: schedule.start}  # an option the env refuses fails here
    probe = make_batch_env(entry.env_id, 1, config.engine, options)  # its spaces size the policy before anything
    try:
        policy = build_policy(config, probe)
        discrete = isinstance(probe.single_action_space, spaces.Discrete)
        check_memory(config, policy)
        spaces_here = (probe.single_observation_space, probe.single_action_space)
        if config.demonstrations:
            check_clonable(policy, entry.demonstrator, entry.env_id)
        start = transferred(config, policy, spaces_here) if config.start_from and not resuming else Transfer()
    finally:
        probe.close()
    if config.demonstrations and not resuming:
        start = demonstrated_start(config, entry, policy, progress)
    eval_env = make_batch_env(entry.env_id, config.measuring.eval_episodes, config.engine)
    try:
        search = build_search(config, policy, discrete, start.center)
        workload = Workload(
            policy,
            RegisteredEnv(entry.env_id, config.engine),
            config.search.popsize,
            config.search.episodes_per_candidate,
            config.max_steps,
            moments=isinstance(config.world, ModelFreeSettings) and bool(config.world.observation_norm),
        )
        evaluator = make_backend(backend, workload, address=address, workers=workers)
    except BaseException:
        eval_env.close()
        raise
    try:
        if config.model_based:
            world: World[Any] = ModelBased(config, entry, policy, eval_env, evaluator, start.model)
        elif isinstance(evaluator, LocalBackend) and isinstance(config.world, ActionSpaceSettings):
            world = ActionSpace(config, policy, evaluator, workload)
        else:
            world = ModelFree(
                config, policy, evaluator, workload, lambda attempt: restarted_search(config, policy, attempt)
            )
    except BaseException:
        evaluator.close()
        eval_env.close()
        raise
    return Setup(config, entry, policy, search, world, world.measured_on(eval_env), start.spent)


def prepare_resume(
    folder: RunFolder, backend: str = "local", address: str | None = None, workers: int | None = None
) -> tuple[Setup, Counters | None]:
    """The run in ``folder`` rebuilt at its checkpoint, its metrics.csv cut back to the checkpoint's step; the folder
    is held by this process from now on (``RunFolder.claim``). A run stopped before its first checkpoint is rebuilt
    at its start (no counters): run again, it gives what it would have, with the same settings and seed.

    A folder that cannot be resumed exactly (a bad config or checkpoint, missing metrics), or that another process
    holds, raises ValueError.
    """
    folder.claim()
    try:
        if folder.stopped_before_its_first_checkpoint():
            return prepare(folder.read_config(), backend, address, workers, resuming=True), None
        config, checkpoint = open_run(folder)
        setup = prepare(config, backend, address, workers, resuming=True)
    except BaseException:
        folder.release()
        raise
    try:
        counters = restore(setup, checkpoint)
        counters.rows = folder.truncate_metrics(counters.iteration, checkpoint.get("metrics"))
        check_rows(counters)
    except BaseException:
        setup.close()
        folder.release()
        raise
    return setup, counters


@dataclass(frozen=True)
class Transfer:
    """What a run starts from instead of its own initial state: another run's policy weights and world model."""

    center: torch.Tensor | None = None
    model: dict[str, torch.Tensor] | None = None
    spent: tuple[int, int] = (0, 0)  # real episodes and steps it took here (demonstrations)


def transferred(config: TrainConfig, policy: Policy, spaces_here: SpacePair) -> Transfer:
    """The best measured centre of the run in ``config.start_from`` and, where both runs are model-based with world
    models of one kind and shape, its model: transfer (thesis 6.2), e.g. a policy and model learned in the simulator
    carried to a robot, where a few real episodes fine-tune the model and the search goes on inside it.

    Refused in one line: a folder that is not a finished or stopped run, another policy, other spaces."""
    folder = RunFolder(Path(str(config.start_from)))
    source, checkpoint = open_run(folder)
    if source.policy != config.policy:
        raise ValueError(f"start_from: {folder.path} trained a {source.policy} policy, this run's is {config.policy}")
    if isinstance(source.world, ModelFreeSettings) and source.world.observation_norm:
        raise ValueError(f"start_from: {folder.path}'s policy reads normalised observations; start from a run without")
    probe = make_batch_env(lookup(source.env).env_id, 1, source.engine)
    try:
        there = (probe.single_observation_space, probe.single_action_space)
        check_same_spaces(source.env, there, config.env, spaces_here)
    finally:
        probe.close()
    model = None
    if source.model_based and config.model_based and same_model(source.model_based, config.model_based):
        model = checkpoint["world"]["model"]
    return Transfer(trained_center(checkpoint, policy), model)


def demonstrated_start(config: TrainConfig, entry: EnvEntry, policy: Policy, progress: bool = False) -> Transfer:
    """The policy cloned from ``config.demonstrations`` real episodes of the env's demonstrator
    (``drrl.training.cloning``), and the real episodes and steps they took."""
    assert entry.demonstrator is not None  # check_clonable
    demonstrations = config.world.start
    assert isinstance(demonstrations, Demonstrations)
    center, recorded = cloned(
        policy,
        entry.demonstrator,
        entry.env_id,
        demonstrations.episodes,
        demonstrations.rounds,
        derive_seed(config.seed, 0, Stream.DEMONSTRATING),
        demonstrations.noise,
        config.engine,
        config.max_steps,
        config.device,
        progress,
    )
    return Transfer(center, spent=(recorded.episodes, recorded.steps))


def same_model(a: ModelBasedSettings, b: ModelBasedSettings) -> bool:
    """Whether two runs' world models have one kind and shape."""
    return all(getattr(a, name) == getattr(b, name) for name in ("model_kind", "hidden", "ensemble_size"))


def open_run(folder: RunFolder) -> tuple[TrainConfig, dict]:
    """A run folder's config and checkpoint for eval and render, each checked: the checkpoint trained with exactly
    this config, of its kind, with every counter and centre well formed."""
    config, checkpoint = folder.load_run()
    check_checkpoint(checkpoint, config.world.kind)
    trained_on = lookup(config.env).env_id
    if checkpoint["env_id"] != trained_on:
        raise ValueError(
            f"checkpoint's env_id {short_repr(checkpoint['env_id'])} does not match config.json's env {config.env} "
            f"({trained_on})"
        )
    return config, checkpoint


def trained_center(checkpoint: dict, policy: Policy, final: bool = False) -> torch.Tensor:
    """The best measured centre (or, ``final``, the last one) for ``policy``, which must have its size."""
    if checkpoint["num_params"] != policy.num_params:
        raise ValueError(
            f"checkpoint holds {checkpoint['num_params']} weights, but its {policy.num_params}-weight "
            f"policy needs as many"
        )
    return checkpoint["center"] if final else checkpoint["best_center"]


def as_read(config: TrainConfig, checkpoint: dict, env: VectorEnv) -> VectorEnv:
    """``env`` as the run's policy reads it: through the run's frame autoencoder where the env observes frames, with
    its world model's memory where the run's policy reads it (``ModelBased.measured_on``)."""
    settings, space = config.model_based, env.single_observation_space
    if settings is None:
        return env
    world = checkpoint["world"]
    autoencoder = None
    if is_frames(space):
        autoencoder = frame_autoencoder(space.shape or (), settings, config.seed)
        load_weights(autoencoder, world["autoencoder"])
    model = None
    if settings.policy_memory:
        size = autoencoder.features if autoencoder else observation_size(space)
        model = build_model(settings, size, env.single_action_space, config.seed)
        load_weights(model, world["model"])
    return reading(env, autoencoder, model)


SpacePair = tuple[spaces.Space, spaces.Space]  # (observation space, action space)


def check_same_spaces(trained_id: str, trained: SpacePair, env_id: str, given: SpacePair) -> None:
    """Refuse to run a policy trained on ``trained_id`` on ``env_id`` unless their (observation, action) spaces
    are the same."""
    if trained != given:
        raise ValueError(
            f"the policy was trained on {trained_id}, whose observation and action spaces {trained} are not "
            f"{env_id}'s {given}"
        )


def subscribers(folder: RunFolder | None, progress: bool, tensorboard: bool = False) -> list[Subscriber]:
    """The model's guard (model-based runs), the run folder's writer (if a folder is given), the progress bar and
    TensorBoard (into the run folder)."""
    attached: list[Subscriber] = [ModelGuard()]
    if folder is not None:
        attached.append(RunFolderWriter(folder))
        if tensorboard:
            attached.append(TensorBoardLogger(folder.path / "tensorboard"))
    if progress:
        attached.append(ProgressBar())
    return attached


def train(
    config: TrainConfig,
    out: Path | None = None,
    progress: bool = False,
    backend: str = "local",
    address: str | None = None,
    workers: int | None = None,
) -> Counters:
    """Spend ``config.budget`` real episodes, model-free or model-based; write a run folder to ``out`` if given."""
    setup = prepare(config, backend, address, workers, progress=progress)
    return run(setup, subscribers(None if out is None else RunFolder.create(out), progress))


def resume(
    path: Path, progress: bool = False, backend: str = "local", address: str | None = None, workers: int | None = None
) -> Counters:
    """Continue the run in folder ``path`` from its checkpoint to the end of its budget."""
    folder = RunFolder(path)
    setup, counters = prepare_resume(folder, backend, address, workers)
    return run(setup, subscribers(folder, progress), counters)
