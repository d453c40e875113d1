"""The training configuration: one typed, validated record, written to every run folder as config.json."""

from __future__ import annotations

import difflib
import json
import tomllib
from pathlib import Path

import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from drrl.envs.batch import ENGINES
from drrl.envs.registry import is_own, lookup
from drrl.models.settings import MODEL_BASED_DEFAULTS, ModelBasedSettings, one_of
from drrl.policy_gradient import POLICY_GRADIENTS
from drrl.search import SEARCHES
from drrl.search.pgpe import FITNESS_SHAPINGS, OPTIMIZERS, SAMPLERS

MAX_CONFIG_BYTES = 1024 * 1024
# Model-free defaults for Gymnasium's envs (not drrl's own): observations are normalised and actions scaled from
# [-1, 1] to the env's bounds, so one σ suits envs of any scale. A linear policy with a bias (the normalisation's
# shift folds into it), small steps and centred ranks, as ARS (Mania et al. 2018) searched MuJoCo's tasks; chosen on
# Acrobot, MountainCarContinuous, InvertedDoublePendulum, Reacher and Hopper (BENCHMARKS.md).
GYMNASIUM_DEFAULTS = {
    "policy": "linear",
    "popsize": 16,
    "sigma_init": 0.025,
    "center_lr": 0.02,
    "fitness_shaping": "centered_ranks",
    "budget": 3200,
}


def env_defaults(env: object, model_based: bool = False) -> dict:
    """The settings measured for ``env`` beyond the general defaults: its registry entry's ``defaults``, or its
    ``model_based_defaults`` for a ``model_based`` run; none for a name that is no env (the env's own check says
    why)."""
    if not isinstance(env, str):
        return {}
    try:
        entry = lookup(env)
    except ValueError:
        return {}
    return dict(entry.model_based_defaults if model_based else entry.defaults)


# Action-space policy gradients' defaults, chosen on the thesis cart-pole among 12 settings each (step rule and size,
# initial action σ, episodes an update; 3 seeds, 2000–3000 episodes): the ones that reached a near-optimal centre in
# the most seeds (BENCHMARKS.md). eNAC's regression needs more episodes an update than REINFORCE's gradient.
POLICY_GRADIENT_DEFAULTS = {
    "reinforce": {"optimizer": "adam", "center_lr": 0.1, "sigma_init": 1.0, "popsize": 16},
    "enac": {"optimizer": "clipup", "center_lr": 0.05, "sigma_init": 0.5, "popsize": 32},
}
CHOICES = {
    "search": (*SEARCHES, *POLICY_GRADIENTS),
    "sampler": SAMPLERS,
    "optimizer": OPTIMIZERS,
    "fitness_shaping": FITNESS_SHAPINGS,
    "engine": ENGINES,
}  # string settings


class EnvSchedule(BaseModel):
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

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    option: str = Field(min_length=1, description="the env's keyword argument, e.g. tolerance")
    start: float = Field(gt=0, le=1e9)
    end: float = Field(gt=0, le=1e9)
    share: float = Field(0.5, gt=0, le=1, description="of the real-episode budget over which the option moves")
    advance_at: float | None = Field(None, description="move a step after a generation whose median return is this")
    steps: int = Field(10, ge=1, le=10_000, description="steps from start to end, with advance_at")

    def value(self, progress: float, stage: int = 0) -> float:
        """The option's value once ``progress`` (0 to 1) of the budget is spent, or, with ``advance_at``, once
        ``stage`` steps are taken."""
        fraction = stage / self.steps if self.advance_at is not None else progress / self.share
        return self.start * (self.end / self.start) ** min(fraction, 1.0)


class TrainConfig(BaseModel):
    """Everything a training run depends on. Defaults solve the thesis's cart-pole (5.1) out of the box.

    The defaults were chosen on that cart-pole (benchmarks/sample_efficiency.py, BENCHMARKS.md): the thesis's
    bias-free linear policy (2.14), symmetric sampling (2.31–2.33), and ClipUp for μ, which reached a near-optimal
    policy in about half the real episodes plain gradient ascent needed; its step size 0.1 (not 0.2) keeps the
    centre from drifting away from the optimum once there.

    ``model_based`` set makes a model-based run; the fields it leaves unset then start from
    ``MODEL_BASED_DEFAULTS`` and the env's own ``EnvEntry.model_based_defaults`` instead of the model-free
    defaults. A model-free run on one of drrl's envs starts from its ``EnvEntry.defaults`` (the swing-up has
    some), on an env that is not drrl's own from ``GYMNASIUM_DEFAULTS`` and what drrl measured for that env
    (``env_defaults``: Pendulum-v1 needs CMA-ES and a nonlinear policy), an action-space policy gradient's from
    ``POLICY_GRADIENT_DEFAULTS``. All merge in one place. sampler,
    optimizer, center_lr, sigma_lr, fitness_shaping, baseline_decay and max_sigma_change are
    PGPE's; CMA-ES (``search = "cmaes"`` or ``"sep-cmaes"``) uses popsize, sigma_init and seed only. The
    action-space policy gradients (``search = "reinforce"`` or ``"enac"``, ``drrl.action_space``) run popsize ×
    episodes_per_candidate episodes an update, start their actions' σ at sigma_init and step θ by optimizer with
    center_lr.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    env: str = "cartpole"
    policy: str = "linear:nobias"
    search: str = "pgpe"
    sampler: str = "symmetric"
    optimizer: str = "clipup"
    fitness_shaping: str = "none"
    popsize: int = Field(8, ge=2, le=1_000_000, description="candidates per generation")
    episodes_per_candidate: int = Field(1, ge=1, le=10_000)
    budget: int = Field(1000, ge=1, le=10**9, description="real training episodes to spend")
    sigma_init: float = Field(1.0, gt=0, le=1e6)
    center_lr: float = Field(0.1, gt=0, le=1e6, description="step size of μ (ClipUp's; its max speed is twice it)")
    sigma_lr: float = Field(0.01, gt=0, le=1e6)
    baseline_decay: float = Field(0.1, ge=0, lt=1)
    max_sigma_change: float = Field(0.2, gt=0, lt=1)
    eval_episodes: int = Field(
        50, ge=1, le=100_000, description="episodes that measure the centre policy (not training)"
    )
    eval_every: int = Field(1, ge=1, le=10**9, description="generations between measurements of the centre policy")
    eval_share: float = Field(
        0.25,
        gt=0,
        le=1,
        description="the most of a model-free run's env steps that measuring may take (1: measure every eval_every)",
    )
    checkpoint_every: int = Field(10, ge=1, le=10**9, description="generations between checkpoints")
    stop_when_solved: bool = Field(
        False,
        description="end the run once a measured centre meets every criterion of the task's verdict, the real "
        "episodes left unspent",
    )
    solved_in_a_row: int = Field(
        1,
        ge=1,
        le=1000,
        description="with stop_when_solved: the measurements in a row whose centre must meet it before the run ends "
        "(more than 1 where a centre that has only just reached the level may not hold it)",
    )
    restart_every: int | None = Field(
        None,
        ge=1,
        le=10**9,
        description="generations an attempt of a model-free search lasts: unless its last centre, measured then, meets "
        "every criterion of the task (and the run ends), the search starts again from a new random centre and seed",
    )
    max_steps: int | None = Field(None, ge=1, le=10**9, description="cut episodes longer than this")
    reward_shift: float = Field(
        0.0,
        ge=-1e6,
        le=1e6,
        description="taken from the reward of every training step the search is told of (measuring sees the env's "
        "own): a survival bonus the search should not chase (Hopper-v5 starts at 1)",
    )
    observation_norm: bool | None = Field(
        None,
        description="feed the policy observations normalised by the mean and "
        "std of all training observations so far (model-free; "
        "unset: on for envs other than drrl's own)",
    )
    seed: int = Field(0, ge=0, le=2**32 - 1)
    device: str = "cpu"
    engine: str = Field(
        "auto",
        description="what steps the env's batch (drrl.envs.batch); a run folder's config names the one its run used",
    )
    model_based: ModelBasedSettings | None = Field(None, description="set: model-based PGPE (drrl.model_based)")
    env_schedule: EnvSchedule | None = Field(None, description="a curriculum on one env option (model-free)")
    demonstrations: int = Field(
        0,
        ge=0,
        le=100_000,
        description="real episodes of the env's scripted demonstrator that the first centre is cloned from "
        "(drrl.cloning), counted in the budget",
    )
    demonstration_rounds: int = Field(
        1,
        ge=1,
        le=1000,
        description="rounds the demonstrations are recorded in, each after the first driven by the clone so far",
    )
    demonstration_noise: float = Field(
        0.05, ge=0, le=10, description="std of the noise added to the demonstrator's raw actions while recording"
    )
    start_from: str | None = Field(
        None,
        max_length=4096,
        description="a run folder whose best measured policy, and world model, this run starts from: transfer, "
        "e.g. from the simulator to a robot (the policy and spaces must be the same)",
    )

    @field_validator(*CHOICES)
    @classmethod
    def _known_choice(cls, value: str, info: ValidationInfo) -> str:
        return one_of(value, CHOICES[str(info.field_name)])

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

    @model_validator(mode="before")
    @classmethod
    def _defaults_for_the_run(cls, data):
        if not isinstance(data, dict):
            return data
        env = data.get("env", "cartpole")
        table = data.get("model_based")
        if table is not None:
            preset = env_defaults(env, model_based=True)
            if isinstance(table, dict):
                table = {**preset.pop("model_based", {}), **table}
            return {**MODEL_BASED_DEFAULTS, **preset, **data, "model_based": table}
        search = data.get("search")
        if isinstance(search, str) and search in POLICY_GRADIENT_DEFAULTS:
            return {**POLICY_GRADIENT_DEFAULTS[search], **data}
        if isinstance(env, str) and not is_own(env):
            return {**GYMNASIUM_DEFAULTS, **env_defaults(env), **data}
        return {**env_defaults(env), **data}

    @model_validator(mode="after")
    def _consistent(self) -> TrainConfig:
        pgpe = self.search == "pgpe"
        if pgpe and self.sampler == "symmetric" and self.popsize % 2:
            raise ValueError(f"symmetric sampling needs an even popsize (pairs μ ± ε), got {self.popsize}")
        if pgpe and self.sampler == "supersymmetric" and self.popsize % 4:
            raise ValueError(f"supersymmetric sampling needs a popsize divisible by 4, got {self.popsize}")
        if self.search in POLICY_GRADIENTS:
            for name, given in (
                ("model_based", self.model_based),
                ("env_schedule", self.env_schedule),
                ("observation_norm", self.observation_norm or None),
            ):
                if given is not None:
                    raise ValueError(f"{name} is for parameter searches (pgpe, cmaes); search {self.search} has none")
        if self.model_based is not None and self.observation_norm:
            raise ValueError(
                "observation_norm is for model-free runs; a model-based run's model normalises its own inputs"
            )
        if self.start_from is not None and self.observation_norm:
            raise ValueError(
                "start_from gives a policy that reads raw observations; set observation_norm to false with it"
            )
        if self.demonstrations and (self.model_based is not None or self.search in POLICY_GRADIENTS):
            raise ValueError("demonstrations start a model-free parameter search (pgpe, cmaes) from their clone")
        if self.demonstrations and self.demonstrations < self.demonstration_rounds:
            raise ValueError(
                f"demonstrations ({self.demonstrations}) must be at least one episode a round "
                f"(demonstration_rounds {self.demonstration_rounds})"
            )
        if self.demonstrations and (self.start_from is not None or self.observation_norm):
            raise ValueError(
                "demonstrations give the first centre, a policy that reads raw observations: not with start_from "
                "or observation_norm"
            )
        if self.restart_every is not None and (
            self.model_based is not None
            or self.search in POLICY_GRADIENTS
            or self.demonstrations
            or self.start_from is not None
        ):
            raise ValueError(
                "restart_every starts a model-free parameter search (pgpe, cmaes) again from a new random centre: not "
                "with model_based, an action-space policy gradient, demonstrations or start_from"
            )
        if self.model_based is not None and self.env_schedule is not None:
            raise ValueError("env_schedule is for model-free runs; a model-based run learns the env as registered")
        if self.model_based is None and self.generations < 1:
            demonstrations = f" less {self.demonstrations} demonstrations" if self.demonstrations else ""
            raise ValueError(
                f"budget of {self.budget} real episodes{demonstrations} is smaller than one generation "
                f"({self.popsize} candidates × {self.episodes_per_candidate} episode(s) each)"
            )
        return self

    @property
    def episodes_per_generation(self) -> int:
        return self.popsize * self.episodes_per_candidate

    @property
    def generations(self) -> int:
        return (self.budget - self.demonstrations) // self.episodes_per_generation


def load_config_file(path: Path) -> dict:
    """Read a TOML or JSON config file into a plain dict (validated later, with command-line overrides)."""
    kind = "JSON" if path.suffix == ".json" else "TOML"
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ValueError(
                f"config file {path} is over {MAX_CONFIG_BYTES // 1024} KiB; a config holds a few settings"
            )
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark is allowed
    except OSError as error:
        raise ValueError(f"cannot read config file {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"config file {path} is not {kind} text: byte {error.start} is not UTF-8") from None
    try:
        settings = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as error:
        raise ValueError(f"config file {path} is not valid {kind}: {error}") from None
    except RecursionError:
        raise ValueError(f"config file {path} nests its tables too deeply to be a drrl config") from None
    if not isinstance(settings, dict):
        raise ValueError(
            f"config file {path} must hold an object of settings (name: value), not a {type(settings).__name__}"
        )
    return settings


def describe_errors(error: ValidationError) -> str:
    """One line per invalid field: the field, the value given and what is allowed."""
    lines = []
    for item in error.errors():
        field = ".".join(str(part) for part in item["loc"]) or "config"
        message = item["msg"].removeprefix("Value error, ")
        if item["type"] == "extra_forbidden" and item["loc"][:-1] in ((), ("model_based",)):
            table = TrainConfig if len(item["loc"]) == 1 else ModelBasedSettings
            message = _unknown_setting(str(item["loc"][-1]), list(table.model_fields))
        given = f" (got {short_repr(item['input'])})" if item["loc"] else ""
        lines.append(f"{field}: {message}{given}")
    return "\n".join(lines)


def _unknown_setting(name: str, known: list[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f"not a setting{f' (did you mean {close[0]}?)' if close else ''}; the settings are: {', '.join(known)}"


def short_repr(value, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters for a one-line message."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
