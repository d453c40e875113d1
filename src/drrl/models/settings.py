"""The settings of model-based PGPE: a typed, validated record that ``TrainConfig.model_based`` holds.

In a model-based run (``drrl.model_based``) the ``TrainConfig`` fields keep their meaning where they can: ``budget``
is the real training episodes to spend, ``eval_episodes`` the real episodes that measure the centre policy, and
the search settings (policy, sampler, optimizer, σ, step sizes) describe PGPE, which now runs inside the learned
model: ``popsize`` × ``episodes_per_candidate`` *imagined* episodes a generation, ``generations`` generations an
iteration. ``MODEL_BASED_DEFAULTS`` are the ``TrainConfig`` values a model-based run starts from.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from drrl.models.fit import MODEL_OPTIMIZERS, FitSettings
from drrl.models.kinds import MODEL_KINDS
from drrl.models.recurrent import FUTURE_INPUTS
from drrl.models.recurrent import MODEL_KINDS as RECURRENT_KINDS

REWARD_MODES = ("auto", "known", "learned")
VALIDATE_EVERY = 100  # gradient steps between two measurements of a fit's held-out loss
MAX_WIDTH = 65_536  # units in a layer: wider is a typo, and would not fit in memory with its neighbours
CHOICES = {
    "model_kind": MODEL_KINDS,
    "future_inputs": FUTURE_INPUTS,
    "reward": REWARD_MODES,
    "model_optimizer": MODEL_OPTIMIZERS,
}  # string settings and what each allows

# TrainConfig values for a model-based run: 20 real episodes; PGPE in the model with 20 candidates × 10 imagined
# episodes (many imagined episodes per candidate are free, and average out the start states).
MODEL_BASED_DEFAULTS = {"popsize": 20, "episodes_per_candidate": 10, "budget": 20}


class ModelBasedSettings(BaseModel):
    """The world model, its fitting, and the data loop around PGPE.

    reward: "known" (the task's reward in closed form on predicted observations, first completed by the entries that
    follow in closed form from the others where the task has such, ``EnvEntry.complete_observation``), "learned" (a
    small network fitted to read the reward and end off the next observation, ``drrl.models.outcome``) or "auto":
    known where drrl knows it (the env's ``EnvEntry.reward``), learned elsewhere. Known is the default where
    possible because the thesis's 5.8 is discontinuous in the state (0 inside |s|, |θ| ≤ 0.05, −1 outside) and
    depends on the step t, which the model does not observe: a learned reward could only blur it, while the closed
    form is exact and free.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    initial_episodes: int = Field(
        2, ge=1, le=1_000_000, description="real episodes of the first iteration (explorers μ ± ε)"
    )
    episodes_per_iteration: int = Field(
        2, ge=1, le=1_000_000, description="real episodes of every later iteration (μ, μ ± ε)"
    )
    generations: int = Field(40, ge=1, le=1_000_000, description="most PGPE generations inside the model per iteration")
    patience: int = Field(
        10,
        ge=1,
        le=1_000_000,
        description="stop the in-model search when the candidates' mean imagined return has not "
        "improved over this many generations",
    )
    imagined_horizon: int | None = Field(
        None,
        ge=1,
        le=10**9,
        description="imagined episodes end after this many steps (unset: at the task's horizon)",
    )
    model_kind: str = "rnn"
    hidden: tuple[int, ...] = Field((64,), min_length=1, description="widths of the stacked layers")
    ensemble_size: int = Field(1, ge=1, le=1000)
    unfold: int = Field(4, ge=1, le=10_000, description="observed steps of a training window (3.3.1)")
    overshoot: int = Field(16, ge=0, le=10_000, description="steps past them with targets (3.3.2)")
    future_inputs: str = "predictions"
    reward: str = "auto"
    disagreement_penalty: float = Field(0.0, ge=0)
    exploration_bonus: float = Field(
        0.0,
        ge=0,
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
    )
    model_optimizer: str = "adam_lambda"
    model_lr: float = Field(1e-2, gt=0, le=1e3)
    fit_batch_size: int = Field(128, ge=1, le=1_000_000)
    fit_updates: int = Field(1000, ge=1, le=10**7, description="most gradient steps of the first fit")
    refit_updates: int = Field(
        400,
        ge=1,
        le=10**7,
        description="most gradient steps of every later fit, which starts from the previous model's weights",
    )
    fit_patience: int = Field(
        5,
        ge=1,
        le=1_000_000,
        description=f"stop a fit once its held-out loss has not improved over this many validations, one every "
        f"{VALIDATE_EVERY} updates",
    )

    latent_size: int = Field(
        8,
        ge=2,
        le=4096,
        multiple_of=2,
        description="frames only: the numbers of a frame's code, the (x, y) of latent_size / 2 keypoints (the latent "
        "state: the newest frame's code and its changes since the older frames)",
    )
    frame_updates: int = Field(
        1000, ge=1, le=10**7, description="frames only: gradient steps of the frame autoencoder's first fit"
    )
    frame_refit_updates: int = Field(
        200, ge=1, le=10**7, description="frames only: gradient steps of every later fit, from the previous weights"
    )

    @field_validator(*CHOICES)
    @classmethod
    def _known_choice(cls, value: str, info: ValidationInfo) -> str:
        return one_of(value, CHOICES[str(info.field_name)])

    @field_validator("hidden")
    @classmethod
    def _positive_widths(cls, value: tuple[int, ...]) -> tuple[int, ...]:
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


def one_of(value: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``; else a ValueError listing them (for pydantic validators)."""
    if value not in choices:
        raise ValueError(f"{value!r} is not one of: {', '.join(choices)}")
    return value
