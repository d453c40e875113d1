"""Recurrent world models (thesis 3.3–3.5) and model-based PGPE: the learned model is a batched env.

Fitting is ``drrl.models.fit.fit``; the model-based loop, a training loop, lives one layer up in
``drrl.model_based``. This package imports nothing of drrl's but itself: a task's closed-form reward comes in as a function.
"""

from drrl.models.data import Episode, EpisodeBuffer, EpisodeRecorder, Windows
from drrl.models.fit import MODEL_OPTIMIZERS, FitReport, FitSettings
from drrl.models.imagined import ImaginedEnv, ImaginedWorld, RewardFunction
from drrl.models.recurrent import (FUTURE_INPUTS, MODEL_KINDS, Prediction, WorldModel, unfolding_loss,
                                   window_losses)
from drrl.models.settings import MODEL_BASED_DEFAULTS, ModelBasedSettings

__all__ = ["FUTURE_INPUTS", "MODEL_BASED_DEFAULTS", "MODEL_KINDS", "MODEL_OPTIMIZERS", "Episode",
           "EpisodeBuffer", "EpisodeRecorder", "FitReport", "FitSettings", "ImaginedEnv", "ImaginedWorld", "RewardFunction",
           "ModelBasedSettings", "Prediction", "Windows", "WorldModel", "unfolding_loss",
           "window_losses"]
