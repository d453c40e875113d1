"""Model-based PGPE: the search pointed at a learned world model, with a data loop around it (thesis 2.3, 5.1).

One step of the loop (``drrl.training.loop.run``) is one iteration:
    1. collect real episodes with the current centre policy μ and exploring candidates μ ± ε from the search;
    2. fit the world model(s) to all real episodes so far (``drrl.models.trainer``; with ``mirror_episodes``, to
       their mirror images too, where the task declares its reflection symmetry; later fits start from the previous
       weights, a recurrent model's fits all hold out the same episodes, and a later fit whose held-out loss
       jumps to ``LOSS_JUMP`` times the last one is done again from new weights, the better of the two kept);
    3. run the search inside the model (an ``ImaginedEnv``, made by every backend worker from an ``ImaginedWorld``),
       from real start states (and their mirror images, with ``mirror_episodes``), for at most
       ``model_based.generations_per_iteration`` generations of ``drrl.training.loop.run_generation``, the model-free
       generation, stopping early once the candidates' mean imagined return stops improving (a generation whose
       candidates all earn the same imagined return widens σ instead, ``drrl.search.pgpe``);
then the loop measures μ on fresh real episodes (``eval_episodes``), counted as evaluation, never as training.
Iterations repeat until the budget of real training episodes is spent. Real steps and episodes are counted exactly
(by ``drrl.rollout.evaluate``); imagined steps and episodes are counted apart. Every iteration is checkpointed with
the model, the real episodes and the search, so a stopped run resumes exactly.

On an env that observes frames (``drrl.envs.pixels``), step 2 starts by fitting a frame autoencoder to every real
frame so far (``drrl.models.frames``) and encoding the real episodes into latent ones; the world model, imagination
and the policy then work on the latent state, and real episodes and measurements see the env through the encoder.
Where no reward is known in closed form (always, on frames), the reward and end are learned from the observations
(``drrl.models.outcome``) after the model is fitted.

Divergence: a model whose loss turns non-finite, or imagined returns that do, stop the run with
``ModelDiverged``; the checkpoint keeps the last whole iteration (its model, real episodes and search), so
nothing before it is lost and no policy is trained on a broken model.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import gymnasium
import numpy as np
import torch
from gymnasium.vector import VectorEnv

from drrl.envs.batch import RegisteredEnv, is_frames
from drrl.envs.registry import EnvEntry
from drrl.models.base import LearnedModel, load_weights, weights
from drrl.models.data import Episode, EpisodeBuffer, EpisodeRecorder, action_size
from drrl.models.frames import Encoding, FrameAutoencoder, fit_autoencoder
from drrl.models.imagined import ImaginedWorld, TaskKnowledge
from drrl.models.kinds import make_model
from drrl.models.outcome import LearnedOutcome, fit_outcome
from drrl.models.recurrent import WorldModel
from drrl.models.remembering import Remembering
from drrl.models.trainer import Fitted, ModelDiverged, ModelTrainer
from drrl.policies import Policy
from drrl.rollout import Backend, Evaluation, NonFiniteOutput, Workload, evaluate
from drrl.search.base import Search
from drrl.settings import ModelBasedSettings, TrainConfig
from drrl.streams import Stream, derive_seed, imagined_seed
from drrl.training.loop import UNITS, Counters, Setup, World, run_generation


class ModelBased(World[Search]):
    """Real episodes feed a world model; the search's generations run inside it, through ``backend``. A step is a
    sequence of its parts: the ``Collector``'s real episodes, the ``ModelTrainer``'s fit, the ``InModelSearch``.

    Each iteration runs on one torch thread: the model's matrices are small (batches of a few hundred rows, widths
    of tens), so a second thread costs more in hand-offs than it gains, and leaves the other core to the machine.
    """

    kind = "model-based"
    unit = UNITS[kind]
    training = "real episodes collected, mean"

    def __init__(
        self,
        config: TrainConfig,
        entry: EnvEntry,
        policy: Policy,
        eval_env: VectorEnv,
        backend: Backend,
        start_model: dict[str, torch.Tensor] | None = None,
    ):
        settings = config.model_based
        if settings is None:
            raise ValueError("a model-based run needs model_based settings")
        if config.budget < settings.initial_episodes:
            raise ValueError(
                f"budget: {config.budget} real episodes is fewer than model_based.initial_episodes "
                f"({settings.initial_episodes}); raise the budget or lower initial_episodes"
            )
        if settings.reward == "known" and entry.reward is None:
            raise ValueError(
                f"model_based.reward: no closed-form reward is known for {entry.env_id!r}; use 'learned' or 'auto'"
            )
        if settings.mirror_episodes and entry.mirror is None:
            raise ValueError(
                f"model_based.mirror_episodes: {entry.env_id!r} declares no reflection symmetry to mirror its "
                f"episodes by (drrl's cart-poles and Pendulum-v1 do); leave mirror_episodes off"
            )
        self.config, self.settings, self.policy, self.backend = config, settings, policy, backend
        self.action_space = eval_env.single_action_space
        seen = eval_env.single_observation_space
        frames = is_frames(seen)
        self.mirror = entry.mirror if settings.mirror_episodes else None
        self.autoencoder = frame_autoencoder(seen.shape or (), settings, config.seed, config.device) if frames else None
        self.frames = EpisodeBuffer()  # the real episodes as frames, where the env observes frames
        observation_size = self.autoencoder.features if self.autoencoder else int(np.prod(seen.shape or ()))
        self.model = build_model(settings, observation_size, eval_env.single_action_space, config.seed, config.device)
        if start_model is not None:  # another run's model to fine-tune (``drrl.training.train.transferred``)
            load_weights(self.model, start_model)
        self.real_horizon = config.max_steps or episode_horizon(entry.env_id, eval_env)
        self.horizon = min(self.real_horizon, settings.imagined_horizon or self.real_horizon)  # the search's
        known = settings.reward in ("auto", "known")
        self.task = task_knowledge(entry, known)
        self.outcome: LearnedOutcome | None = None  # the reward and end learned where none is known
        self.buffer = EpisodeBuffer()
        self.sizes = iteration_sizes(config.budget, settings)
        self.collector = Collector(config, settings, policy, RegisteredEnv(entry.env_id, config.engine), self.sizes)
        first, later = (settings.fit_settings(first, learn_reward=False) for first in (True, False))
        self.trainer = ModelTrainer(self.model, first, later, config.seed, self.mirror)
        self.imagination = InModelSearch(config, settings, policy, backend, self.imagined_world, self.real_horizon)

    @property
    def iterations(self) -> int:
        return len(self.sizes)

    @property
    def real_budget(self) -> int:
        return sum(self.sizes)

    def step(self, setup: Setup[Search], counters: Counters, iteration: int) -> dict:
        """Collect, fit, search in the model (module docstring); the iteration's metrics row."""
        search = setup.search
        setup.report("collecting real episodes")
        episodes, real = self.collector.collect(search, counters, iteration, self.measured_on, self.imagination)
        last = counters.rows[-1].get("fit_time") if counters.rows else None
        setup.report(f"fitting the world model{'' if last is None else f' (the last fit took {last:.0f} s)'}")
        fit_start = time.perf_counter()
        seeing = self.remember(episodes, iteration)

        def fitting(updates: int, most: int) -> None:
            setup.report(f"fitting the world model: {progress_of('update', updates, most, fit_start)}")

        fitted = self.trainer.fit(self.buffer, iteration, fitting)
        self.learn_outcome(iteration)
        search_start = time.perf_counter()
        searched = self.imagination.improve(search, counters, iteration, setup.report)
        times = {"fit_time": round(search_start - fit_start, 3), "search_time": round(searched.end - search_start, 3)}
        return metrics_row(iteration, counters, real, fitted, searched, search) | seeing | times

    def remember(self, episodes: list[Episode], iteration: int) -> dict:
        """Add the real ``episodes`` to the buffer the model learns from (on frames, through the autoencoder fitted
        anew, ``see``); the autoencoder's figures for the row, if any."""
        if self.autoencoder is None:
            self.buffer.extend(episodes)
            return {}
        self.frames.extend(episodes)
        return self.see(iteration)

    def learn_outcome(self, iteration: int) -> None:
        """Where no reward is known, learn the reward and end from the real episodes (``drrl.models.outcome``)."""
        if self.task.reward is None:
            seed = derive_seed(self.config.seed, iteration, Stream.FITTING)
            self.outcome = fit_outcome(self.buffer, self.task.end_reward, seed=seed)

    def see(self, iteration: int) -> dict:
        """Fit the frame autoencoder to every real frame so far (from its previous weights after the first fit) and
        encode the real episodes into the latent ones the world model learns from (the codes the fit's standardising
        computed); the fit's figures for the row."""
        assert self.autoencoder is not None
        episodes = self.frames.episodes
        fit = fit_autoencoder(
            self.autoencoder,
            np.concatenate([episode.observations for episode in episodes]),
            self.settings.frame_updates if iteration == 1 else self.settings.frame_refit_updates,
            seed=derive_seed(self.config.seed, iteration, Stream.SEEING),
        )
        latent = np.split(fit.features, np.cumsum([len(episode.observations) for episode in episodes])[:-1])
        self.buffer = EpisodeBuffer(
            [dataclasses.replace(episode, observations=z) for episode, z in zip(episodes, latent, strict=True)]
        )
        return {"frame_loss": fit.loss, "frame_updates": fit.updates}

    def measured_on(self, env: VectorEnv) -> VectorEnv:
        """``env`` as the policy reads it, in measuring and collecting alike: through the frame autoencoder where it
        observes frames (their latent), with the world model's memory beside the observation where the settings ask
        for it."""
        return reading(env, self.autoencoder, self.model if self.settings.policy_memory else None)

    def imagined_world(self, disagreement_penalty: float, horizon: int | None = None) -> ImaginedWorld:
        """The current model as imagined episodes from the real start states so far (and their mirror images, with
        ``mirror_episodes``), ``horizon`` steps long (the search's horizon unless given), rewarded as the task is
        known or learned."""
        starts = self.buffer.start_observations()
        if self.mirror is not None:  # the task's starts are symmetric too
            no_actions = np.zeros((0, action_size(self.action_space)), np.float32)
            starts = np.concatenate([starts, self.mirror(starts, no_actions)[0]])
        task = self.task if self.outcome is None else dataclasses.replace(self.task, reward=self.outcome)
        return ImaginedWorld.of(
            self.model,
            starts,
            self.action_space,
            horizon or self.horizon,
            task,
            disagreement_penalty,
            self.settings.policy_memory,
        )

    def state_dict(self) -> dict:
        state = {
            "model": weights(self.model),
            "buffer": self.buffer.state_dict() if len(self.buffer) else {},
            "trainer": self.trainer.state_dict(),
        }
        if self.autoencoder is not None:
            state["autoencoder"] = weights(self.autoencoder)
            state["frames"] = self.frames.state_dict() if len(self.frames) else {}
        return state

    def load_state_dict(self, state: dict) -> None:
        load_weights(self.model, state["model"])
        self.buffer = EpisodeBuffer.from_state_dict(state["buffer"]) if state["buffer"] else EpisodeBuffer()
        self.trainer.load_state_dict(state["trainer"])
        if self.autoencoder is not None:
            load_weights(self.autoencoder, state["autoencoder"])
            self.frames = EpisodeBuffer.from_state_dict(state["frames"]) if state["frames"] else EpisodeBuffer()

    def title(self, setup: Setup) -> str:
        settings = self.settings
        return (
            f"{setup.entry.env_id}, {self.config.policy} policy, model-based {self.config.search.name} "
            f"({settings.model_kind} {'×'.join(map(str, settings.hidden))}, K = {settings.ensemble_size})"
        )

    def close(self) -> None:
        self.backend.close()


class Collector:
    """Step 1, the iteration's real episodes: the centre μ and explorers μ ± ε from the search (only explorers before
    a model has informed μ), or with an exploration bonus the explorers the model is most optimistic about."""

    def __init__(
        self, config: TrainConfig, settings: ModelBasedSettings, policy: Policy, real: RegisteredEnv, sizes: list[int]
    ):
        self.config, self.settings, self.policy, self.real, self.sizes = config, settings, policy, real, sizes

    def collect(
        self,
        search: Search,
        counters: Counters,
        iteration: int,
        read: Callable[[VectorEnv], VectorEnv],
        imagination: InModelSearch,
    ) -> tuple[list[Episode], Evaluation]:
        """Iteration ``iteration``'s recorded real episodes, the policies reading the env through ``read``, and what
        they spent (counted in ``counters``)."""
        count = self.sizes[iteration - 1]
        params = exploring_policies(search, count, with_center=iteration > 1 or self.config.start_from is not None)
        if self.settings.exploration_bonus and iteration > 1 and count > 1:  # explorers beside μ to choose
            params = torch.cat([params[:1], imagination.optimistic_explorers(search, count - 1, counters, iteration)])
        config = self.config
        episodes, real = collect(
            self.policy,
            params,
            self.real,
            derive_seed(config.seed, iteration, Stream.TRAINING),
            config.max_steps,
            read,
        )
        counters.real_episodes += real.episodes
        counters.real_steps += real.steps
        return episodes, real


@dataclass(frozen=True)
class Searched:
    """What an iteration's search in the model did, for the row."""

    generations: int
    tied: int  # generations whose candidates all earned the same imagined return
    promised: float  # the kept centre's imagined return over a real episode's horizon
    kept: bool  # the old centre kept (keep_unless_improved)
    end: float  # ``time.perf_counter()`` when the generations ended


class InModelSearch:
    """Step 3, the search inside the model, from real start states: generations on imagined episodes made by
    ``imagined(disagreement_penalty, horizon)`` (``ModelBased.imagined_world``) through ``backend``, then the new
    centre's imagined return, and with ``keep_unless_improved`` the search undone unless the model promises the new
    centre more than the old one."""

    def __init__(
        self,
        config: TrainConfig,
        settings: ModelBasedSettings,
        policy: Policy,
        backend: Backend,
        imagined: Callable[..., ImaginedWorld],
        real_horizon: int,
    ):
        self.config, self.settings, self.policy, self.backend = config, settings, policy, backend
        self.imagined, self.real_horizon = imagined, real_horizon

    def improve(self, search: Search, counters: Counters, iteration: int, report: Callable[[str], None]) -> Searched:
        """Iteration ``iteration``'s generations in the model, counted in ``counters``."""
        config = self.config
        imagined = self.imagined(self.settings.disagreement_penalty)
        self.backend.use(
            Workload(
                self.policy, imagined, config.search.popsize, config.search.episodes_per_candidate, config.max_steps
            )
        )
        before = search.state_dict() if self.settings.keep_unless_improved else None
        old_center = search.center
        generations, tied = self.generations(search, counters, iteration, report)
        end = time.perf_counter()
        # the centre in the model, as long as a real episode (the loop measures it in reality); where it may be kept,
        # the old one beside it on the same starts
        centers = [search.center] if before is None else [search.center, old_center]
        in_model = self.imagine_centers(torch.stack(centers), iteration)
        kept = False
        if before is not None and in_model[0] <= in_model[1]:
            search.load_state_dict(before)
            kept = True
        return Searched(generations, tied, float(in_model[1 if kept else 0]), kept, end)

    def generations(
        self, search: Search, counters: Counters, iteration: int, report: Callable[[str], None]
    ) -> tuple[int, int]:
        """Generations on imagined episodes, counted in ``counters``; returns how many ran, and in how many every
        candidate's imagined return was the same (no gradient: PGPE widens σ, ``drrl.search.pgpe``). ``report``
        is told each one, with the time the rest would take at most.

        Stops early (beyond the thesis, for speed) once the best mean imagined return of a generation's candidates
        has not improved for ``patience`` generations: the search has converged on this model, and more generations
        would only fit the model's errors.
        """
        best, since_best, generation, tied = float("-inf"), 0, 0, 0
        most, start = self.settings.generations_per_iteration, time.perf_counter()
        for generation in range(1, most + 1):
            seed = imagined_seed(self.config.seed, iteration, generation)
            try:
                evaluation, metrics = run_generation(
                    search, self.backend, seed, reward_shift=self.settings.reward_shift
                )
            except NonFiniteOutput as error:
                raise ModelDiverged(
                    f"iteration {iteration}, generation {generation}: the model imagined {error}; "
                    f"stopped before updating the search"
                ) from None
            counters.generations += 1
            counters.imagined_episodes += evaluation.episodes
            counters.imagined_steps += evaluation.steps
            tied += int(metrics.get("tied", 0))
            mean = float(evaluation.returns.mean())
            best, since_best = (mean, 0) if mean > best else (best, since_best + 1)
            if since_best >= self.settings.patience:
                break
            report(f"searching in the model: {progress_of('generation', generation, most, start)}")
        return generation, tied

    def imagine_centers(self, centers: torch.Tensor, iteration: int) -> torch.Tensor:
        """The imagined returns (C,) of ``centers`` (C, n) over a real episode's horizon, each on the same
        imagined starts (common random numbers): what the model promises each in reality."""
        episodes = self.config.episodes_per_generation
        env = self.imagined(self.settings.disagreement_penalty, self.real_horizon).make(len(centers) * episodes)
        seed = derive_seed(self.config.seed, iteration, Stream.IMAGINING)
        return evaluate(self.policy, centers, env, episodes, seed=seed).returns

    def optimistic_explorers(self, search: Search, count: int, counters: Counters, iteration: int) -> torch.Tensor:
        """Of the search's candidates μ ± ε, the ``count`` whose imagined episode earns the most reward plus
        ``exploration_bonus`` × the members' disagreement along the way (every candidate from the same real start):
        real episodes go where the model expects much or knows little, which is where they teach it most.

        Beyond the thesis, which explores with random μ ± ε; the bonus is the ensemble's own uncertainty, the
        optimism in the face of uncertainty of model-based exploration (e.g. PETS-style ensembles).
        """
        candidates = search.ask()
        env = self.imagined(-self.settings.exploration_bonus).make(len(candidates))  # disagreement earns
        seed = derive_seed(self.config.seed, iteration, Stream.EXPLORING)
        evaluation = evaluate(self.policy, candidates, env, 1, seed=seed, max_steps=self.config.max_steps)
        counters.imagined_episodes += evaluation.episodes
        counters.imagined_steps += evaluation.steps
        return candidates[torch.argsort(evaluation.returns, descending=True, stable=True)[:count]]


def task_knowledge(entry: EnvEntry, known: bool) -> TaskKnowledge:
    """What imagined episodes know of ``entry``'s task: its reward in closed form, the action cost and the observation
    completion where that reward is ``known`` to be used; else the reward of a terminating step, for the learned
    reward (``drrl.models.outcome``)."""
    reward = entry.reward if known else None
    return TaskKnowledge(
        reward=reward,
        action_cost=entry.action_cost if known else None,
        complete_observation=entry.complete_observation if known else None,
        end_reward=None if reward else entry.end_reward,
    )


def metrics_row(
    iteration: int, counters: Counters, real: Evaluation, fitted: Fitted, searched: Searched, search: Search
) -> dict:
    """Iteration ``iteration``'s metrics row (without the frame autoencoder's figures and the times)."""
    return {
        "iteration": iteration,
        "real_episodes": counters.real_episodes,
        "real_steps": counters.real_steps,
        "imagined_episodes": counters.imagined_episodes,
        "imagined_steps": counters.imagined_steps,
        "generations": searched.generations,
        "tied_generations": searched.tied,
        "mean_return": float(real.returns.mean()),
        "imagined_center_return": searched.promised,
        "kept_center": int(searched.kept),
        "sigma_norm": float(search.spread.norm()),
        "overshoot": fitted.overshoot,
        "model_loss": fitted.loss,
        "held_out_episodes": fitted.held_out_episodes,
        "refitted": int(fitted.refitted),
        "fit_updates": sum(report.updates for report in fitted.reports),
    }


def iteration_sizes(budget: int, settings: ModelBasedSettings) -> list[int]:
    """Real episodes collected by each iteration, within the budget (a remainder too small for an iteration is
    left unspent)."""
    later = (budget - settings.initial_episodes) // settings.episodes_per_iteration
    return [settings.initial_episodes] + [settings.episodes_per_iteration] * later


def build_model(
    settings: ModelBasedSettings, observation_size: int, action_space: gymnasium.Space, seed: int, device: str = "cpu"
) -> LearnedModel:
    """The ensemble of world models ``settings`` describes, for observations of ``observation_size`` numbers."""
    return make_model(
        settings.model_kind,
        observation_size=observation_size,
        action_size=action_size(action_space),
        hidden=settings.hidden,
        future_inputs=settings.future_inputs,
        members=settings.ensemble_size,
        seed=seed,
        device=device,
    )


def frame_autoencoder(
    shape: tuple[int, ...], settings: ModelBasedSettings, seed: int, device: str = "cpu"
) -> FrameAutoencoder:
    """The frame autoencoder for frames of ``shape`` (F, H, W), its initial weights drawn from ``seed``."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return FrameAutoencoder((shape[0], shape[1], shape[2]), settings.latent_size).to(device)


def episode_horizon(env_id: str, env: VectorEnv) -> int:
    """The steps after which the real env truncates an episode: its task's horizon or its registered limit."""
    task = getattr(env, "task", None)
    if task is not None:
        return int(task.horizon)
    limit = gymnasium.spec(env_id).max_episode_steps
    if limit is None:
        raise ValueError(f"{env_id} has no registered episode limit; set max_steps for imagined episodes")
    return int(limit)


def exploring_policies(search: Search, count: int, with_center: bool) -> torch.Tensor:
    """``count`` policies for real episodes: μ itself (if ``with_center``), then candidates μ ± ε drawn with the
    search's current σ."""
    candidates = search.ask()
    while len(candidates) < count:
        candidates = torch.cat([candidates, search.ask()])
    if with_center:
        return torch.cat([search.center[None], candidates[: count - 1]])
    return candidates[:count]


def reading(env: VectorEnv, autoencoder: FrameAutoencoder | None, model: LearnedModel | None) -> VectorEnv:
    """``env`` through ``autoencoder`` (frames to their latent) and with ``model``'s memory beside each
    observation, each where given."""
    encoded = env if autoencoder is None else Encoding(env, autoencoder)
    if model is None:
        return encoded
    assert isinstance(model, WorldModel)  # the settings allow a memory of recurrent models only
    return Remembering(encoded, model)


def collect(
    policy: Policy,
    params: torch.Tensor,
    source: RegisteredEnv,
    seed: int,
    max_steps: int | None,
    read: Callable[[VectorEnv], VectorEnv] = lambda env: env,
) -> tuple[list[Episode], Evaluation]:
    """One recorded real episode per row of ``params``, and the exact steps and episodes spent; the policies read
    the env through ``read`` (``ModelBased.measured_on``), and the episodes hold what the env gave (frames).

    The env is seeded here so that every episode starts from its own state: ``evaluate``'s seeding gives every
    candidate the same start (common random numbers), which would make all the collected episodes start alike.
    """
    recorder = EpisodeRecorder(source.make(len(params)))
    env = read(recorder)
    try:
        env.reset(seed=seed)
        evaluation = evaluate(policy, params, env, 1, seed=None, max_steps=max_steps)
        return recorder.episodes(), evaluation
    finally:
        env.close()


def progress_of(unit: str, done: int, most: int, start: float) -> str:
    """``done`` of at most ``most`` steps of a phase that began at ``start`` (``time.perf_counter``), and the time
    the rest would take at most, at the pace so far."""
    left = (time.perf_counter() - start) / done * (most - done)
    return f"{unit} {done} of at most {most}, {left:.0f} s left at most"
