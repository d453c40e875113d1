"""The world model's fitting over a model-based run (``drrl.training.model_based``'s step 2): one fit an iteration, to
every real episode so far, for every kind of model alike (``drrl.models.kinds.fit_model``).

The first fit starts from the model's initial weights, later ones from the previous weights (with their own,
usually fewer, updates); a recurrent model's fits all hold out the same episodes (one split seed for the run), so
its held-out losses compare from fit to fit. Beyond the thesis: a warm-started fit whose held-out loss jumps to
``LOSS_JUMP`` times the last one is done again from new weights on the same split, and the better of the two kept.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drrl.models.base import LearnedModel
from drrl.models.data import EpisodeBuffer, Mirror
from drrl.models.fit import FitReport, FitSettings
from drrl.models.kinds import fit_model, remake
from drrl.streams import Stream, derive_seed

LOSS_JUMP = 4.0  # a fit whose held-out loss exceeds the last iteration's this many times is done again afresh


class ModelDiverged(RuntimeError):
    """The world model's loss, or the returns imagined in it, turned non-finite; the run stopped, its checkpoint
    holding the last whole iteration."""


@dataclass(frozen=True)
class Fitted:
    """An iteration's fit: the kept model's reports (one per member), the overshooting horizon it used, and whether
    it was done again from new weights."""

    reports: list[FitReport]
    overshoot: int
    refitted: bool

    @property
    def loss(self) -> float:
        return held_out_loss(self.reports)

    @property
    def held_out_episodes(self) -> int:
        return self.reports[0].held_out_episodes


class ModelTrainer:
    """Fits ``model`` in place, iteration after iteration: the first fit (and a fit afresh) as ``first``, later
    ones as ``later``, their random numbers drawn from the run's ``seed``; keeps the last fit's held-out loss, the
    one the next fit is compared with (in its ``state_dict``)."""

    def __init__(
        self, model: LearnedModel, first: FitSettings, later: FitSettings, seed: int, mirror: Mirror | None = None
    ):
        self.model, self.first, self.later, self.seed, self.mirror = model, first, later, seed, mirror
        self.split_seed = derive_seed(seed, 0, Stream.FITTING)  # one for every fit: episodes held out stay so
        self.last_loss: float | None = None  # the last fit's held-out loss, where it held episodes out

    def fit(self, buffer: EpisodeBuffer, iteration: int, progress: Callable[[int, int], None] | None = None) -> Fitted:
        """Iteration ``iteration``'s fit to ``buffer``, done again afresh if its held-out loss jumped;
        ``ModelDiverged`` if the model's loss turned non-finite. ``progress(updates, most)`` is told as it goes."""
        settings = fitting_settings(self.first if iteration == 1 else self.later, buffer)
        seed = derive_seed(self.seed, iteration, Stream.FITTING)
        reports = fit_model(self.model, buffer, settings, seed, self.split_seed, self.mirror, progress)
        if any(report.stop == "diverged" for report in reports):
            raise ModelDiverged(f"iteration {iteration}: the world model's loss turned non-finite")
        jumped = self.last_loss is not None and held_out_loss(reports) > LOSS_JUMP * self.last_loss
        refitted = bool(reports[0].held_out_episodes and jumped)  # held-out losses both, not training losses
        if refitted:
            reports = self.refit_afresh(buffer, reports, iteration)
        self.last_loss = held_out_loss(reports) if reports[0].held_out_episodes else None
        return Fitted(reports, settings.overshoot, refitted)

    def refit_afresh(self, buffer: EpisodeBuffer, reports: list[FitReport], iteration: int) -> list[FitReport]:
        """Fit a model from new initial weights, as the first fit does, on the same split; keep it if its held-out
        loss is lower than the warm-started fit's (``reports``). Returns the kept model's reports.

        Beyond the thesis: a warm-started fit can be left far worse on held-out episodes than the model before it
        (new data the old weights cannot bend to), and a policy searched in that model fails in reality.
        """
        seed = derive_seed(self.seed, iteration, Stream.FITTING)
        fresh = remake(self.model, seed)
        settings = fitting_settings(self.first, buffer)
        fresh_reports = fit_model(fresh, buffer, settings, seed, self.split_seed, self.mirror)
        worse = held_out_loss(fresh_reports) >= held_out_loss(reports)
        if worse or any(report.stop == "diverged" for report in fresh_reports):
            return reports
        self.model.load_state_dict(fresh.state_dict())
        return fresh_reports

    def state_dict(self) -> dict:
        return {"last_loss": self.last_loss}

    def load_state_dict(self, state: dict) -> None:
        self.last_loss = state["last_loss"]


def held_out_loss(reports: list[FitReport]) -> float:
    """The members' mean loss on their held-out episodes."""
    return float(np.mean([report.valid_loss for report in reports]))


def fitting_settings(settings: FitSettings, buffer: EpisodeBuffer) -> FitSettings:
    """``settings`` with the window shortened while every real episode so far is shorter than one (the first
    episodes of a falling pole can be; a hand of Blackjack lasts one to three steps): first the overshooting
    horizon, then the unfolded steps; the iteration's row reports the horizon used."""
    longest = max(len(episode) for episode in buffer.episodes)
    if longest >= settings.unfold + settings.overshoot:
        return settings
    unfold = min(settings.unfold, longest)
    return dataclasses.replace(settings, unfold=unfold, overshoot=longest - unfold)
