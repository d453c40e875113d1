"""``TrainConfig``: a run's settings (``parts.RunSettings``), also read from the flat form people write."""

from __future__ import annotations

from pydantic import model_validator

from drrl.settings.flat import flattened, is_flat, merged, nested
from drrl.settings.parts import RunSettings


class TrainConfig(RunSettings):
    """Everything a training run depends on. Given in the flat form (``TrainConfig(env="cartpole-swingup",
    model_based={})``, a TOML file), it starts from the task's presets (``drrl.settings.presets``) and the given
    settings win; given in the nested form (config.json), it is taken as it is."""

    @model_validator(mode="before")
    @classmethod
    def _flat_form(cls, data):
        return nested(data) if is_flat(data) else data

    def updated(self, **settings) -> TrainConfig:
        """This run's settings with some replaced, given by their flat names (``popsize=4``,
        ``model_based={"ensemble_size": 5}``, a table merged setting by setting), validated again."""
        return TrainConfig.model_validate(merged([("run", flattened(self)), ("given", settings)])[0])
