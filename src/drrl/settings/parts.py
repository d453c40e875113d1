"""A run's settings as a record of parts, each a pydantic model that validates only itself.

    TrainConfig: env, policy, budget, max_steps, seed, device, engine
        measuring: Measuring
        world: ModelFreeSettings   {search: PGPE | CMA-ES,      start: Demonstrations | StartFrom | None, ...}
             | ModelBasedSettings  {search: PGPE | CMA-ES,      start: StartFrom | None, the model, its fitting, ...}
             | ActionSpaceSettings {search: REINFORCE | eNAC,   start: StartFrom | None, ...}

A setting that belongs to another part cannot be given: a CMA-ES search has no sampler, a model-based world no
``observation_norm``, an action-space run no demonstrations. Every field's ``description`` is its one description,
which ``drrl train --help``, the settings reference and the error for a bad value all show.

People write settings in the flat form (``drrl.settings.flat``): ``popsize = 20`` rather than
``world.search.popsize``, a ``[model_based]`` table for a model-based world. config.json holds this nested form.
"""

from __future__ import annotations

from typing import Annotated, Literal

import torch
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationInfo,
    field_validator,
    model_validator,
)

from drrl.envs.batch import ENGINES
from drrl.models.fit import MODEL_OPTIMIZERS, FitSettings
from drrl.models.kinds import MODEL_KINDS
from drrl.models.recurrent import FUTURE_INPUTS
from drrl.models.recurrent import MODEL_KINDS as RECURRENT_KINDS
from drrl.policies import ACCEPTED_FORMS, parse_spec
from drrl.search.pgpe import FITNESS_SHAPINGS, OPTIMIZERS, SAMPLERS, check_whole_draws

REWARD_MODES = ("auto", "known", "learned")
VALIDATE_EVERY = 100  # gradient steps between two measurements of a fit's held-out loss
MAX_WIDTH = 65_536  # units in a layer: wider is a typo, and would not fit in memory with its neighbours
PARAMETER_SEARCHES = ("pgpe", "cmaes", "sep-cmaes")
POLICY_GRADIENTS = ("reinforce", "enac")


def one_of(value: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``; else a ValueError listing them (for pydantic validators)."""
    if value not in choices:
        raise ValueError(f"{value!r} is not one of: {', '.join(choices)}")
    return value


def choice(default: str, choices: tuple[str, ...], description: str):
    """A string field that must be one of ``choices`` (checked by ``Part``), with its description."""
    return Field(default, description=description, json_schema_extra={"choices": list(choices)})


class Part(BaseModel):
    """One part of a run's settings: unknown fields refused, no NaN or infinity, string choices checked."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)

    @field_validator("*")
    @classmethod
    def _known_choice(cls, value, info: ValidationInfo):
        field = cls.model_fields[str(info.field_name)]
        choices = (field.json_schema_extra or {}).get("choices") if isinstance(field.json_schema_extra, dict) else None
        return (
            one_of(value, tuple(map(str, choices))) if isinstance(choices, list) and isinstance(value, str) else value
        )


def _number_only(value):
    """A number setting takes numbers only: not true/false (TOML's booleans, which pydantic would read as 1 and 0)
    and not text ("1_0", which Python reads as 10)."""
    if isinstance(value, (bool, str)):
        raise ValueError(f"must be a number, not {'true/false' if isinstance(value, bool) else 'text'}")
    return value


Int = Annotated[int, BeforeValidator(_number_only)]
Float = Annotated[float, BeforeValidator(_number_only)]


def _default(part: type[Part]):
    """A part's default: its own defaults, made afresh for every record."""
    return lambda: part.model_validate({})


# ---------------------------------------------------------------------------------------------------- searches


class Sampled(Part):
    """What every search shares: candidates a generation, their episodes, the initial spread."""

    popsize: Int = Field(8, ge=2, le=1_000_000, description="candidates per generation")
    episodes_per_candidate: Int = Field(1, ge=1, le=10_000, description="episodes per candidate")
    sigma_init: Float = Field(
        1.0, gt=0, le=1e6, description="initial σ of every parameter (reinforce, enac: of every action)"
    )

    @field_validator("sigma_init")
    @classmethod
    def _representable(cls, value: float) -> float:
        if torch.tensor(value, dtype=torch.float32).item() == 0:
            raise ValueError("must be at least 1.2e-38: a smaller σ is 0 in float32, and the search would not explore")
        return value


class Stepped(Part):
    """A search that steps its centre μ by a step rule."""

    optimizer: str = choice("clipup", OPTIMIZERS, "step rule for μ")
    center_lr: Float = Field(0.1, gt=0, le=1e6, description="step size of μ (ClipUp's; its max speed is twice it)")


class PGPESettings(Stepped, Sampled):
    """PGPE (thesis 2.4, Algorithm 2; ``drrl.search.pgpe``)."""

    name: Literal["pgpe"] = Field("pgpe", description="the search: pgpe (the thesis), cmaes, sep-cmaes")
    sampler: str = choice(
        "symmetric",
        SAMPLERS,
        "PGPE's sampler: single candidates (2.28-2.29), symmetric pairs μ ± ε (SyS, 2.31-2.33) or supersymmetric "
        "quadruples",
    )
    sigma_lr: Float = Field(0.01, gt=0, le=1e6, description="learning rate of σ")
    fitness_shaping: str = choice("none", FITNESS_SHAPINGS, "fitness shaping")
    baseline_decay: Float = Field(0.1, ge=0, le=1, description="the old baseline's weight in 2.33")
    max_sigma_change: Float = Field(0.2, gt=0, lt=1, description="the most |Δσ/σ| of one step")

    @model_validator(mode="after")
    def _whole_draws(self) -> PGPESettings:
        check_whole_draws(self.sampler, self.popsize)
        return self


class CMAESSettings(Sampled):
    """CMA-ES with a full (cmaes) or diagonal (sep-cmaes) covariance (``drrl.search.cmaes``)."""

    name: Literal["cmaes", "sep-cmaes"] = Field("cmaes", description="the search: cmaes or sep-cmaes")


class PolicyGradientSettings(Stepped, Sampled):
    """An action-space policy gradient (thesis 2.1.4, 2.2.2; ``drrl.training.action_space``): popsize ×
    episodes_per_candidate exploring episodes an update, σ that of the actions."""

    name: Literal["reinforce", "enac"] = Field(description="the policy gradient: reinforce or enac")


ParameterSearch = Annotated[PGPESettings | CMAESSettings, Field(discriminator="name")]


# ---------------------------------------------------------------------------------------------------- starts


class Demonstrations(Part):
    """The first centre cloned from real episodes of the env's scripted demonstrator (``drrl.training.cloning``)."""

    episodes: Int = Field(
        ge=1,
        le=100_000,
        description="real episodes of the env's scripted demonstrator (the stacking tasks' with end-point actions) "
        "that the first centre is cloned from, counted in the budget",
    )
    rounds: Int = Field(
        1,
        ge=1,
        le=1000,
        description="rounds the demonstrations are recorded in, each after the first driven by the clone so far",
    )
    noise: Float = Field(0.05, ge=0, le=10, description="std of the noise on the demonstrator's raw actions")

    @model_validator(mode="after")
    def _an_episode_a_round(self) -> Demonstrations:
        if self.episodes < self.rounds:
            raise ValueError(
                f"demonstrations ({self.episodes}) must be at least one episode a round (demonstration_rounds "
                f"{self.rounds})"
            )
        return self


class StartFrom(Part):
    """Transfer (thesis 6.2): another run's best measured policy and, model-based, its world model."""

    run: str = Field(
        min_length=1,
        max_length=4096,
        description="a run folder whose best measured policy (and world model) this run starts from, e.g. one "
        "trained in the simulator for a run on the robot (the policy and spaces must be the same)",
    )


def _start_kind(value) -> str:
    """Which start a model-free run's ``start`` is: another run's (``run`` alone) or demonstrations, so that a bad
    value is reported against that one start only."""
    if isinstance(value, dict):
        return StartFrom.__name__ if "run" in value and "episodes" not in value else Demonstrations.__name__
    return type(value).__name__


ModelFreeStart = Annotated[
    Annotated[Demonstrations, Tag(Demonstrations.__name__)] | Annotated[StartFrom, Tag(StartFrom.__name__)],
    Discriminator(_start_kind),
]

# ---------------------------------------------------------------------------------------------------- worlds


class EnvSchedule(Part):
    """A curriculum (beyond the thesis): one numeric keyword argument of the env, ``option``, moved geometrically from
    ``start`` to ``end``, then held there. It shapes the training episodes only: measuring, ``drrl eval`` and ``drrl
    render`` see the env as registered.

    It moves over the first ``share`` of the real-episode budget, or, with ``advance_at`` set, by one of ``steps``
    equal geometric steps after each generation whose median candidate returned at least ``advance_at``: as fast as
    the search keeps up, where a schedule by the budget can outrun it and leave every return tied.

    Why: a sparse reward gives a search nothing to rank. On Baxter's two-arm reach (reward 5.10) no candidate of a
    fresh policy brings both end-points within 0.05 m of their targets, so every return is −2000; a tolerance that
    starts at 0.5 m and shrinks to 0.05 m pays for getting closer from the first generation.
    """

    option: str = Field(min_length=1, description="the env's keyword argument, e.g. tolerance")
    start: Float = Field(gt=0, le=1e9, description="the option's value at the start")
    end: Float = Field(gt=0, le=1e9, description="the option's value at the end")
    share: Float = Field(0.5, gt=0, le=1, description="of the real-episode budget over which the option moves")
    advance_at: Float | None = Field(None, description="move a step after a generation whose median return is this")
    steps: Int = Field(10, ge=1, le=10_000, description="steps from start to end, with advance_at")

    def value(self, progress: float, stage: int = 0) -> float:
        """The option's value once ``progress`` (0 to 1) of the budget is spent, or, with ``advance_at``, once
        ``stage`` steps are taken."""
        fraction = stage / self.steps if self.advance_at is not None else progress / self.share
        return self.start * (self.end / self.start) ** min(fraction, 1.0)


class Shifted(Part):
    """A world whose search is told of rewards less a shift."""

    reward_shift: Float = Field(
        0.0,
        ge=-1e6,
        le=1e6,
        description="taken from the reward of every training step, real or imagined, the search is told of "
        "(measuring sees the env's own): a survival bonus the search should not chase (Hopper-v5 starts at 1)",
    )


class RealGenerations(Shifted):
    """What a world whose every step is a generation on the real env shares (model-free, action-space)."""

    eval_every: Int = Field(1, ge=1, le=10**9, description="generations between measurements of the centre policy")
    eval_share: Float = Field(
        0.25, gt=0, le=1, description="the most of the run's env steps that measuring may take (1: every eval_every)"
    )
    checkpoint_every: Int = Field(10, ge=1, le=10**9, description="generations between checkpoints")


class ModelFreeSettings(RealGenerations):
    """Every generation on the real env (``drrl.training.model_free``)."""

    kind: Literal["model-free"] = "model-free"
    search: ParameterSearch = Field(
        default_factory=_default(PGPESettings), description="the search over the policy's weights"
    )
    start: ModelFreeStart | None = Field(None, description="what the first centre is")
    observation_norm: bool | None = Field(
        None,
        description="feed the policy observations normalised by the mean and std of all training observations so far "
        "(unset: on for envs other than drrl's own, unless the run starts from demonstrations or another run)",
    )
    restart_every: Int | None = Field(
        None,
        ge=1,
        le=10**9,
        description="generations an attempt of the search lasts: unless its last centre, measured then, meets every "
        "criterion of the task (and the run ends), the search starts again from a new random centre and seed",
    )
    env_schedule: EnvSchedule | None = Field(None, description="a curriculum on one env option")

    @model_validator(mode="after")
    def _raw_observations_from_a_start(self) -> ModelFreeSettings:
        if self.start is not None and self.observation_norm:
            raise ValueError(
                f"{start_name(self.start)} give a first centre that reads raw observations; set observation_norm to "
                f"false with it"
            )
        if self.start is not None and self.restart_every is not None:
            raise ValueError(
                f"restart_every starts the search again from a new random centre, which would drop the "
                f"{start_name(self.start)}; give one of them"
            )
        return self


class ActionSpaceSettings(RealGenerations):
    """Model-free updates from episodes that explore by action (``drrl.training.action_space``)."""

    kind: Literal["action-space"] = "action-space"
    search: PolicyGradientSettings = Field(description="the action-space policy gradient")
    start: StartFrom | None = Field(None, description="what the first centre is")


class ModelBasedSettings(Shifted):
    """Model-based PGPE (thesis 2.3; ``drrl.training.model_based``): the world model, its fitting, and the data loop
    around the search, which runs inside the model: popsize × episodes_per_candidate *imagined* episodes a generation.

    reward: "known" (the task's reward in closed form on predicted observations, first completed by the entries that
    follow in closed form from the others where the task has such, ``EnvEntry.complete_observation``), "learned" (a
    small network fitted to read the reward and end off the next observation, ``drrl.models.outcome``) or "auto":
    known where drrl knows it (the env's ``EnvEntry.reward``), learned elsewhere. Known is the default where
    possible because the thesis's 5.8 is discontinuous in the state (0 inside |s|, |θ| ≤ 0.05, −1 outside) and
    depends on the step t, which the model does not observe: a learned reward could only blur it, while the closed
    form is exact and free.
    """

    kind: Literal["model-based"] = "model-based"
    search: ParameterSearch = Field(default_factory=_default(PGPESettings), description="the search inside the model")
    start: StartFrom | None = Field(None, description="what the first centre (and model) is")
    # the data loop
    initial_episodes: Int = Field(
        2, ge=1, le=1_000_000, description="real episodes of the first iteration (explorers μ ± ε)"
    )
    episodes_per_iteration: Int = Field(
        2, ge=1, le=1_000_000, description="real episodes of every later iteration (μ, μ ± ε)"
    )
    generations_per_iteration: Int = Field(
        40,
        ge=1,
        le=1_000_000,
        description="most generations of the search inside the model per iteration",
        json_schema_extra={"flag": "generations-per-iteration"},
    )
    patience: Int = Field(
        10,
        ge=1,
        le=1_000_000,
        description="stop the in-model search when the candidates' mean imagined return has not improved over this "
        "many generations",
    )
    imagined_horizon: Int | None = Field(
        None, ge=1, le=10**9, description="imagined episodes end after this many steps (unset: at the task's horizon)"
    )
    reward: str = choice("auto", REWARD_MODES, "the imagined episodes' reward and end: known, learned or auto")
    disagreement_penalty: Float = Field(
        0.0, ge=0, le=1e6, description="taken from an imagined step's reward, times the ensemble's disagreement"
    )
    exploration_bonus: Float = Field(
        0.0,
        ge=0,
        le=1e6,
        description="0: real explorers are random candidates μ ± ε; above 0: the candidates with the highest "
        "imagined return plus this times the ensemble's disagreement (needs ensemble_size ≥ 2)",
    )
    keep_unless_improved: bool = Field(
        False,
        description="after the search in the model, go back to the search's state before it unless the new centre's "
        "imagined return beats the old centre's in the same model, on the same imagined starts",
    )
    mirror_episodes: bool = Field(
        False,
        description="also fit the world model to every real episode's mirror image under the task's reflection "
        "symmetry (the cart-poles' and Pendulum-v1's left-right flip), and start imagined episodes from the "
        "mirrored real starts too: twice the data for no real episode; needs an env that declares its symmetry",
    )
    policy_memory: bool = Field(
        False,
        description="the policy also reads the world model's memory, its last layer's hidden state after the steps "
        "so far (drrl.models.remembering); needs a recurrent model_kind and ensemble_size 1",
        json_schema_extra={"flag": "policy-memory"},
    )
    # the model
    model_kind: str = Field(
        "rnn",
        description="world model: state-space RNN (3.4), LSTM (3.5.2), their layers without memory (mlp), or linear "
        "or sparse polynomial, fitted by least squares",
        json_schema_extra={"choices": list(MODEL_KINDS), "flag": "model-kind"},
    )
    hidden: tuple[Int, ...] = Field(
        (64,),
        min_length=1,
        description="widths of the world model's stacked layers",
        json_schema_extra={"flag": "model-hidden"},
    )
    ensemble_size: Int = Field(
        1, ge=1, le=1000, description="world models in the ensemble", json_schema_extra={"flag": "ensemble"}
    )
    unfold: Int = Field(4, ge=1, le=10_000, description="observed steps of a training window (3.3.1)")
    overshoot: Int = Field(
        16, ge=0, le=10_000, description="steps past them with targets (3.3.2)", json_schema_extra={"flag": "overshoot"}
    )
    future_inputs: str = choice("predictions", FUTURE_INPUTS, "what the overshooting steps are fed (3.3.3)")
    # its fitting
    model_optimizer: str = choice("adam_lambda", MODEL_OPTIMIZERS, "the model's optimizer: NAG (3.24), Adam-λ, ...")
    model_lr: Float = Field(1e-2, gt=0, le=1e3, description="the model optimizer's step size")
    fit_batch_size: Int = Field(
        128, ge=1, le=1_000_000, description="windows a gradient step (at most 8 times the windows the data hold)"
    )
    fit_updates: Int = Field(1000, ge=1, le=10**7, description="most gradient steps of the first fit")
    refit_updates: Int = Field(
        400,
        ge=1,
        le=10**7,
        description="most gradient steps of every later fit, which starts from the previous model's weights",
    )
    fit_patience: Int = Field(
        5,
        ge=1,
        le=1_000_000,
        description=f"stop a fit once its held-out loss has not improved over this many validations, one every "
        f"{VALIDATE_EVERY} updates",
    )
    # frames
    latent_size: Int = Field(
        8,
        ge=2,
        le=4096,
        multiple_of=2,
        description="frames only: the numbers of a frame's code, the (x, y) of latent_size / 2 keypoints (the latent "
        "state: the newest frame's code and its changes since the older frames)",
    )
    frame_updates: Int = Field(
        1000, ge=1, le=10**7, description="frames only: gradient steps of the frame autoencoder's first fit"
    )
    frame_refit_updates: Int = Field(
        200, ge=1, le=10**7, description="frames only: gradient steps of every later fit, from the previous weights"
    )

    @field_validator("hidden")
    @classmethod
    def _positive_widths(cls, value: tuple[Int, ...]) -> tuple[Int, ...]:
        if min(value) < 1 or max(value) > MAX_WIDTH:
            raise ValueError(f"every layer width must be in [1, {MAX_WIDTH}], got {value}")
        return value

    @model_validator(mode="after")
    def _bonus_needs_an_ensemble(self) -> ModelBasedSettings:
        if self.exploration_bonus and self.ensemble_size < 2:
            raise ValueError(
                "exploration_bonus rewards the ensemble's disagreement, which needs ensemble_size ≥ 2 "
                f"(got {self.ensemble_size}); raise ensemble_size or set exploration_bonus to 0"
            )
        return self

    @model_validator(mode="after")
    def _memory_of_one_recurrent_model(self) -> ModelBasedSettings:
        if self.policy_memory and (self.model_kind not in RECURRENT_KINDS or self.ensemble_size != 1):
            raise ValueError(
                "policy_memory reads the hidden state of one recurrent model: it needs model_kind 'rnn' or 'lstm' "
                f"and ensemble_size 1 (got {self.model_kind!r} and {self.ensemble_size})"
            )
        return self

    def memory_size(self) -> int:
        """The numbers of the model's memory the policy reads beside the observation (0 without policy_memory)."""
        return self.hidden[-1] if self.policy_memory else 0

    def fit_settings(self, first: bool, learn_reward: bool) -> FitSettings:
        """How to fit the model in the first iteration (``first``) or a later one."""
        return FitSettings(
            unfold=self.unfold,
            overshoot=self.overshoot,
            learn_reward=learn_reward,
            optimizer=self.model_optimizer,
            lr=self.model_lr,
            batch_size=self.fit_batch_size,
            max_updates=self.fit_updates if first else self.refit_updates,
            validate_every=min(VALIDATE_EVERY, self.fit_updates if first else self.refit_updates),
            patience=self.fit_patience,
        )


World = Annotated[ModelFreeSettings | ModelBasedSettings | ActionSpaceSettings, Field(discriminator="kind")]
Search = PGPESettings | CMAESSettings | PolicyGradientSettings


def start_name(start: Demonstrations | StartFrom) -> str:
    return "demonstrations" if isinstance(start, Demonstrations) else "start_from"


# ---------------------------------------------------------------------------------------------------- the run


class Measuring(Part):
    """How the centre policy is measured, on real episodes counted apart from training, and when a run stops."""

    eval_episodes: Int = Field(
        50, ge=1, le=100_000, description="episodes that measure the centre policy (not training)"
    )
    stop_when_solved: bool = Field(
        False,
        description="end the run once a measured centre meets every criterion of the task's verdict, the real "
        "episodes left unspent",
    )
    solved_in_a_row: Int = Field(
        1,
        ge=1,
        le=1000,
        description="with stop_when_solved: the measurements in a row whose centre must meet it before the run ends "
        "(more than 1 where a centre that has only just reached the level may not hold it)",
    )


class RunSettings(Part):
    """Everything a training run depends on, as parts (the module docstring); ``drrl.settings.TrainConfig`` adds the
    flat form. Defaults solve the thesis's cart-pole (5.1) out of the box.

    The defaults were chosen on that cart-pole (benchmarks/sample_efficiency.py, BENCHMARKS.md): the thesis's
    bias-free linear policy (2.14), symmetric sampling (2.31–2.33), and ClipUp for μ, which reached a near-optimal
    policy in about half the real episodes plain gradient ascent needed; its step size 0.1 (not 0.2) keeps the
    centre from drifting away from the optimum once there. Every other task's settings are presets
    (``drrl.settings.presets``), which settings given in the flat form start from (``drrl.settings.flat``).
    """

    env: str = Field("cartpole", description="the environment: a drrl alias or any Gymnasium id")
    policy: str = Field("linear:nobias", description=ACCEPTED_FORMS)
    budget: Int = Field(1000, ge=1, le=10**9, description="real training episodes to spend")
    max_steps: Int | None = Field(None, ge=1, le=10**9, description="cut episodes longer than this")
    seed: Int = Field(0, ge=0, le=2**32 - 1, description="random seed")
    device: str = Field("cpu", description="the torch device the search runs on: cpu or cuda")
    engine: str = choice(
        "auto",
        ENGINES,
        "what steps the env's batch: drrl's own (native), Gymnasium's classic-control tasks compiled (numba), EnvPool "
        "(envpool), Gymnasium's envs in turn (gymnasium) or over a process per core (processes), or the first that "
        "can (auto); a run folder's config names the one its run used",
    )
    measuring: Measuring = Field(default_factory=_default(Measuring), description="how the centre policy is measured")
    world: World = Field(
        default_factory=_default(ModelFreeSettings), description="where the search's returns come from"
    )

    @field_validator("policy")
    @classmethod
    def _policy_spec(cls, spec: str) -> str:
        parse_spec(spec)
        return spec

    @field_validator("device")
    @classmethod
    def _usable_device(cls, value: str) -> str:
        usable = "cpu" + (", cuda" if torch.cuda.is_available() else "")
        try:
            device = torch.device(value)
        except (RuntimeError, TypeError):
            raise ValueError(f"not a torch device; usable here: {usable}") from None
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"torch sees no CUDA device here; usable here: {usable}")
        if device.type not in ("cpu", "cuda"):
            raise ValueError(f"drrl runs on cpu or cuda; usable here: {usable}")
        return value

    @model_validator(mode="after")
    def _a_generation_in_the_budget(self) -> RunSettings:
        if isinstance(self.world, RealGenerations) and self.total_generations < 1:
            demonstrations = f" less {self.demonstrations} demonstrations" if self.demonstrations else ""
            raise ValueError(
                f"budget of {self.budget} real episodes{demonstrations} is smaller than one generation "
                f"({self.search.popsize} candidates × {self.search.episodes_per_candidate} episode(s) each)"
            )
        return self

    @property
    def search(self) -> Search:
        """The search's settings, in whichever world."""
        return self.world.search

    @property
    def model_based(self) -> ModelBasedSettings | None:
        """The model-based world's settings; None for a run on the real env."""
        return self.world if isinstance(self.world, ModelBasedSettings) else None

    @property
    def start_from(self) -> str | None:
        """The run folder this run starts from, if any."""
        return self.world.start.run if isinstance(self.world.start, StartFrom) else None

    @property
    def demonstrations(self) -> int:
        """The demonstrated episodes the first centre is cloned from (0: none)."""
        return self.world.start.episodes if isinstance(self.world.start, Demonstrations) else 0

    @property
    def episodes_per_generation(self) -> int:
        return self.search.popsize * self.search.episodes_per_candidate

    @property
    def total_generations(self) -> int:
        """The generations on the real env the budget pays for (model-free and action-space runs)."""
        return (self.budget - self.demonstrations) // self.episodes_per_generation
