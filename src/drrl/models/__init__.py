"""Recurrent world models (thesis 3.3–3.5): learned models of an environment, their fitting, and the model as a
batched env.

The interface is ``LearnedModel``; fitting is ``drrl.models.fit.fit``; the model-based world,
a part of the training loop, lives one layer up in ``drrl.training.model_based``. This package imports of drrl only the
Elman policies' cell (``drrl.policies.recurrent``); a task's closed-form reward comes in as a function.
"""

from drrl.models.base import LearnedModel, Prediction
from drrl.models.data import Episode, EpisodeBuffer, EpisodeRecorder, Windows
from drrl.models.fit import MODEL_OPTIMIZERS, FitReport, FitSettings
from drrl.models.imagined import ImaginedEnv, ImaginedWorld, RewardFunction, TaskKnowledge
from drrl.models.kinds import MODEL_KINDS
from drrl.models.linear import LinearModel
from drrl.models.polynomial import PolynomialModel
from drrl.models.recurrent import FUTURE_INPUTS, WorldModel, unfolding_loss, window_losses

__all__ = [
    "FUTURE_INPUTS",
    "MODEL_KINDS",
    "MODEL_OPTIMIZERS",
    "Episode",
    "EpisodeBuffer",
    "EpisodeRecorder",
    "FitReport",
    "FitSettings",
    "ImaginedEnv",
    "ImaginedWorld",
    "LearnedModel",
    "LinearModel",
    "PolynomialModel",
    "Prediction",
    "RewardFunction",
    "TaskKnowledge",
    "Windows",
    "WorldModel",
    "unfolding_loss",
    "window_losses",
]
