"""Model-based PGPE: the search pointed at a learned world model, with a data loop around it (thesis 2.3, 5.1).

One step of the loop (``drrl.loop.run``) is one iteration:
    1. collect real episodes with the current centre policy μ and exploring candidates μ ± ε from the search;
    2. fit the world model(s) to all real episodes so far (``drrl.models.fit``; with ``mirror_episodes``, to their
       mirror images too, where the task declares its reflection symmetry; later fits start from the previous
       weights, a recurrent model's fits all hold out the same episodes, and a later fit whose held-out loss
       jumps to ``LOSS_JUMP`` times the last one is done again from new weights, the better of the two kept);
    3. run the search inside the model (an ``ImaginedEnv``, made by every backend worker from an ``ImaginedWorld``),
       from real start states (and their mirror images, with ``mirror_episodes``), for at most
       ``model_based.generations`` generations of ``drrl.loop.run_generation``, the model-free generation,
       stopping early once the candidates' mean imagined return stops improving (a generation whose candidates all
       earn the same imagined return widens σ instead, ``drrl.search.pgpe``);
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

import gymnasium
import numpy as np
import torch
from gymnasium.vector import VectorEnv

from drrl.envs.batch import RegisteredEnv, is_frames
from drrl.envs.registry import EnvEntry
from drrl.loop import TRAINING, Counters, Setup, World, derive_seed, run_generation
from drrl.models.base import LearnedModel, load_weights, weights
from drrl.models.data import Episode, EpisodeBuffer, EpisodeRecorder, action_size
from drrl.models.fit import FitReport, FitSettings
from drrl.models.frames import Encoding, FrameAutoencoder, fit_autoencoder
from drrl.models.imagined import ImaginedWorld
from drrl.models.kinds import fit_model, make_model, remake
from drrl.models.outcome import LearnedOutcome, fit_outcome
from drrl.models.recurrent import WorldModel
from drrl.models.remembering import Remembering
from drrl.policies import Policy
from drrl.rollout import Backend, Evaluation, NonFiniteOutput, Workload, evaluate
from drrl.search.base import Search
from drrl.settings import ModelBasedSettings, TrainConfig

# random streams of imagined episodes, model fitting and choosing explorers, apart from training and measuring
IMAGINING, FITTING, EXPLORING, SEEING = 2, 3, 4, 5
LOSS_JUMP = 4.0  # a fit whose held-out loss exceeds the last iteration's this many times is done again afresh


class ModelDiverged(RuntimeError):
    """The world model's loss, or the returns imagined in it, turned non-finite; the run stopped, its checkpoint
    holding the last whole iteration."""


class ModelBased(World):
    """Real episodes feed a world model; the search's generations run inside it, through ``backend``.

    Each iteration runs on one torch thread: the model's matrices are small (batches of a few hundred rows, widths
    of tens), so a second thread costs more in hand-offs than it gains, and leaves the other core to the machine.
    """

    kind, unit = "model-based", "iteration"
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
        self.real = RegisteredEnv(entry.env_id, config.engine)
        self.action_space = eval_env.single_action_space
        seen = eval_env.single_observation_space
        frames = is_frames(seen)
        self.mirror = entry.mirror if settings.mirror_episodes else None
        self.autoencoder = frame_autoencoder(seen.shape or (), settings, config.seed, config.device) if frames else None
        self.frames = EpisodeBuffer()  # the real episodes as frames, where the env observes frames
        observation_size = self.autoencoder.features if self.autoencoder else int(np.prod(seen.shape or ()))
        self.model = build_model(settings, observation_size, eval_env.single_action_space, config.seed, config.device)
        if start_model is not None:  # another run's model to fine-tune (``drrl.train.transferred``)
            load_weights(self.model, start_model)
        self.real_horizon = config.max_steps or episode_horizon(entry.env_id, eval_env)
        self.horizon = min(self.real_horizon, settings.imagined_horizon or self.real_horizon)  # the search's
        known = settings.reward in ("auto", "known")
        self.known_reward = entry.reward if known else None
        self.complete_observation = entry.complete_observation if known else None
        self.action_cost = entry.action_cost if known else None
        self.end_reward = None if self.known_reward else entry.end_reward
        self.outcome: LearnedOutcome | None = None  # the reward and end learned where none is known
        self.buffer = EpisodeBuffer()
        self.split_seed = derive_seed(config.seed, 0, FITTING)  # one for every fit: episodes held out stay so
        self.sizes = iteration_sizes(config.budget, settings)

    @property
    def iterations(self) -> int:
        return len(self.sizes)

    @property
    def real_budget(self) -> int:
        return sum(self.sizes)

    def step(self, setup: Setup, counters: Counters, iteration: int) -> dict:
        """Collect, fit, search in the model (module docstring); the iteration's metrics row."""
        config, search = self.config, setup.search
        assert isinstance(search, Search)
        # 1. real episodes: the centre and explorers (only explorers before a model has informed μ)
        count = self.sizes[iteration - 1]
        params = exploring_policies(search, count, with_center=iteration > 1 or self.config.start_from is not None)
        if self.settings.exploration_bonus and iteration > 1 and count > 1:  # explorers beside μ to choose
            params = torch.cat([params[:1], self.optimistic_explorers(search, count - 1, counters, iteration)])
        episodes, real = collect(
            self.policy,
            params,
            self.real,
            derive_seed(config.seed, iteration, TRAINING),
            config.max_steps,
            self.measured_on,
        )
        counters.real_episodes += real.episodes
        counters.real_steps += real.steps
        # 2. the model (on frames, first what it reads of them)
        fit_start = time.perf_counter()
        seeing = {}
        if self.autoencoder is None:
            self.buffer.extend(episodes)
        else:
            self.frames.extend(episodes)
            seeing = self.see(iteration)
        fit_now = fitting_settings(self.settings.fit_settings(iteration == 1, False), self.buffer)
        seed = derive_seed(config.seed, iteration, FITTING)
        reports = fit_model(self.model, self.buffer, fit_now, seed, self.split_seed, self.mirror)
        if any(report.stop == "diverged" for report in reports):
            raise ModelDiverged(f"iteration {iteration}: the world model's loss turned non-finite")
        previous = counters.rows[-1] if counters.rows else {}
        refitted = bool(  # held-out losses both, not training losses standing in for them
            reports[0].held_out_episodes
            and previous.get("held_out_episodes")
            and held_out_loss(reports) > LOSS_JUMP * previous["model_loss"]
        )
        if refitted:
            reports = self.refit_afresh(reports, iteration)
        if self.known_reward is None:
            self.outcome = fit_outcome(self.buffer, self.end_reward, seed=seed)
        # 3. the search inside it, from real start states
        search_start = time.perf_counter()
        imagined = self.imagined_world(self.settings.disagreement_penalty)
        self.backend.use(
            Workload(
                self.policy, imagined, config.search.popsize, config.search.episodes_per_candidate, config.max_steps
            )
        )
        before = search.state_dict() if self.settings.keep_unless_improved else None
        old_center = search.center
        generations, tied = self.search_in_model(search, counters, iteration)
        search_end = time.perf_counter()
        # the centre in the model, as long as a real episode (the loop measures it in reality); where it may be kept,
        # the old one beside it on the same starts
        centers = [search.center] if before is None else [search.center, old_center]
        in_model = self.imagine_centers(torch.stack(centers), iteration)
        kept = False
        if before is not None and in_model[0] <= in_model[1]:
            search.load_state_dict(before)
            kept = True
        return {
            "iteration": iteration,
            "real_episodes": counters.real_episodes,
            "real_steps": counters.real_steps,
            "imagined_episodes": counters.imagined_episodes,
            "imagined_steps": counters.imagined_steps,
            "generations": generations,
            "tied_generations": tied,
            "mean_return": float(real.returns.mean()),
            "imagined_center_return": float(in_model[1 if kept else 0]),
            "kept_center": int(kept),
            "sigma_norm": float(search.spread.norm()),
            "overshoot": fit_now.overshoot,
            "model_loss": held_out_loss(reports),
            "held_out_episodes": reports[0].held_out_episodes,
            "refitted": int(refitted),
            "fit_updates": sum(report.updates for report in reports),
            **seeing,
            "fit_time": round(search_start - fit_start, 3),
            "search_time": round(search_end - search_start, 3),
        }

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
            seed=derive_seed(self.config.seed, iteration, SEEING),
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

    def imagine_centers(self, centers: torch.Tensor, iteration: int) -> torch.Tensor:
        """The imagined returns (C,) of ``centers`` (C, n) over a real episode's horizon, each on the same
        imagined starts (common random numbers): what the model promises each in reality."""
        episodes = self.config.episodes_per_generation
        env = self.imagined_world(self.settings.disagreement_penalty, self.real_horizon).make(len(centers) * episodes)
        seed = derive_seed(self.config.seed, iteration, IMAGINING)
        return evaluate(self.policy, centers, env, episodes, seed=seed).returns

    def optimistic_explorers(self, search: Search, count: int, counters: Counters, iteration: int) -> torch.Tensor:
        """Of the search's candidates μ ± ε, the ``count`` whose imagined episode earns the most reward plus
        ``exploration_bonus`` × the members' disagreement along the way (every candidate from the same real start):
        real episodes go where the model expects much or knows little, which is where they teach it most.

        Beyond the thesis, which explores with random μ ± ε; the bonus is the ensemble's own uncertainty, the
        optimism in the face of uncertainty of model-based exploration (e.g. PETS-style ensembles).
        """
        candidates = search.ask()
        env = self.imagined_world(-self.settings.exploration_bonus).make(len(candidates))  # disagreement earns
        seed = derive_seed(self.config.seed, iteration, EXPLORING)
        evaluation = evaluate(self.policy, candidates, env, 1, seed=seed, max_steps=self.config.max_steps)
        counters.imagined_episodes += evaluation.episodes
        counters.imagined_steps += evaluation.steps
        return candidates[torch.argsort(evaluation.returns, descending=True, stable=True)[:count]]

    def imagined_world(self, disagreement_penalty: float, horizon: int | None = None) -> ImaginedWorld:
        """The current model as imagined episodes from the real start states so far (and their mirror images, with
        ``mirror_episodes``), ``horizon`` steps long (the search's horizon unless given)."""
        starts = self.buffer.start_observations()
        if self.mirror is not None:  # the task's starts are symmetric too
            no_actions = np.zeros((0, action_size(self.action_space)), np.float32)
            starts = np.concatenate([starts, self.mirror(starts, no_actions)[0]])
        return ImaginedWorld.of(
            self.model,
            starts,
            self.action_space,
            horizon or self.horizon,
            self.known_reward or self.outcome,
            disagreement_penalty,
            self.complete_observation,
            self.settings.policy_memory,
            self.action_cost,
        )

    def refit_afresh(self, reports: list[FitReport], iteration: int) -> list[FitReport]:
        """Fit a model from new initial weights, as the first fit does, on the same split; keep it if its held-out
        loss is lower than the warm-started fit's (``reports``). Returns the kept model's reports.

        Beyond the thesis: a warm-started fit can be left far worse on held-out episodes than the model before it
        (new data the old weights cannot bend to), and a policy searched in that model fails in reality.
        """
        seed = derive_seed(self.config.seed, iteration, FITTING)
        fresh = remake(self.model, seed)
        settings = fitting_settings(self.settings.fit_settings(True, False), self.buffer)
        fresh_reports = fit_model(fresh, self.buffer, settings, seed, self.split_seed, self.mirror)
        worse = held_out_loss(fresh_reports) >= held_out_loss(reports)
        if worse or any(report.stop == "diverged" for report in fresh_reports):
            return reports
        self.model.load_state_dict(fresh.state_dict())
        return fresh_reports

    def search_in_model(self, search: Search, counters: Counters, iteration: int) -> tuple[int, int]:
        """Generations on imagined episodes, counted in ``counters``; returns how many ran, and in how many every
        candidate's imagined return was the same (no gradient: PGPE widens σ, ``drrl.search.pgpe``).

        Stops early (beyond the thesis, for speed) once the best mean imagined return of a generation's candidates
        has not improved for ``patience`` generations: the search has converged on this model, and more generations
        would only fit the model's errors.
        """
        best, since_best, generation, tied = float("-inf"), 0, 0, 0
        for generation in range(1, self.settings.generations_per_iteration + 1):
            seed = derive_seed(self.config.seed, iteration * 1_000_000 + generation, IMAGINING)
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
        return generation, tied

    def state_dict(self) -> dict:
        state = {"model": weights(self.model), "buffer": self.buffer.state_dict() if len(self.buffer) else {}}
        if self.autoencoder is not None:
            state["autoencoder"] = weights(self.autoencoder)
            state["frames"] = self.frames.state_dict() if len(self.frames) else {}
        return state

    def load_state_dict(self, state: dict) -> None:
        load_weights(self.model, state["model"])
        self.buffer = EpisodeBuffer.from_state_dict(state["buffer"]) if state["buffer"] else EpisodeBuffer()
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


def held_out_loss(reports: list[FitReport]) -> float:
    """The members' mean loss on their held-out episodes."""
    return float(np.mean([report.valid_loss for report in reports]))


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


def fitting_settings(settings: FitSettings, buffer: EpisodeBuffer) -> FitSettings:
    """``settings`` with the window shortened while every real episode so far is shorter than one (the first
    episodes of a falling pole can be; a hand of Blackjack lasts one to three steps): first the overshooting
    horizon, then the unfolded steps; the iteration's row reports the horizon used."""
    longest = max(len(episode) for episode in buffer.episodes)
    if longest >= settings.unfold + settings.overshoot:
        return settings
    unfold = min(settings.unfold, longest)
    return dataclasses.replace(settings, unfold=unfold, overshoot=longest - unfold)
