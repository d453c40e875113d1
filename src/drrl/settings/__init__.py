"""A run's settings: parts that validate themselves (``parts``), the flat form people write them in (``flat``), every
task's presets (``presets``), and settings files and their errors (``files``)."""

from drrl.settings.config import TrainConfig
from drrl.settings.files import describe_errors, load_config_file, short_repr
from drrl.settings.parts import (
    ActionSpaceSettings,
    CMAESSettings,
    Demonstrations,
    EnvSchedule,
    Measuring,
    ModelBasedSettings,
    ModelFreeSettings,
    PGPESettings,
    PolicyGradientSettings,
    StartFrom,
)

__all__ = [
    "ActionSpaceSettings",
    "CMAESSettings",
    "Demonstrations",
    "EnvSchedule",
    "Measuring",
    "ModelBasedSettings",
    "ModelFreeSettings",
    "PGPESettings",
    "PolicyGradientSettings",
    "StartFrom",
    "TrainConfig",
    "describe_errors",
    "load_config_file",
    "short_repr",
]
