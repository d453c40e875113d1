"""The kinds of world model a model-based run can use, each one module behind ``LearnedModel``: how to build one
and how to fit it to real episodes (its fitter, registered in ``FITTERS`` by its class: a new kind is a module and a
row here).

| kind | module | fitted by |
| --- | --- | --- |
| "rnn", "lstm" | ``drrl.models.recurrent`` (thesis 3.3–3.5) | back-propagation through time (``drrl.models.fit``) |
| "mlp" | ``drrl.models.recurrent`` (its layers without the recurrence) | the same |
| "linear" | ``drrl.models.linear`` (3.3, identity activation) | least squares (``drrl.models.linear``) |
| "polynomial" | ``drrl.models.polynomial`` (the linear model on monomials) | sparse least squares (SINDy) |
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from drrl.models.base import LearnedModel
from drrl.models.data import EpisodeBuffer, Mirror
from drrl.models.fit import FitReport, FitSettings, fit
from drrl.models.linear import LinearModel, fit_linear
from drrl.models.polynomial import PolynomialModel
from drrl.models.recurrent import NETWORK_KINDS, WorldModel

LEAST_SQUARES = {"linear": LinearModel, "polynomial": PolynomialModel}  # the kinds fitted in closed form
MODEL_KINDS = (*NETWORK_KINDS, *LEAST_SQUARES)
# (model, buffer, settings, seed, split_seed, mirror, progress) -> a report per member, the model fitted in place
Fitter = Callable[..., list[FitReport]]


def fit_least_squares(
    model: LinearModel,
    buffer: EpisodeBuffer,
    settings: FitSettings,
    seed: int = 0,
    split_seed: int | None = None,
    mirror: Mirror | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[FitReport]:
    """``fit_linear``, whose held-out episodes are drawn from ``seed`` at every fit, as each fit starts from
    nothing (``split_seed`` places only the recurrent models' held-out episodes); one solve, so no ``progress``."""
    return fit_linear(model, buffer, settings, seed, mirror)


FITTERS: dict[type, Fitter] = {WorldModel: fit, LinearModel: fit_least_squares, PolynomialModel: fit_least_squares}


def make_model(
    kind: str,
    observation_size: int,
    action_size: int,
    hidden: Sequence[int] = (64,),
    future_inputs: str = "predictions",
    members: int = 1,
    seed: int = 0,
    device: torch.device | str = "cpu",
) -> LearnedModel:
    """A world model of ``kind`` on ``device``, its initial weights drawn from ``seed``, the global generator
    untouched (``hidden`` and ``future_inputs`` shape the recurrent kinds only)."""
    if kind not in MODEL_KINDS:
        raise ValueError(f"unknown model kind {kind!r}; choose one of: {', '.join(MODEL_KINDS)}")
    if kind in LEAST_SQUARES:
        return LEAST_SQUARES[kind](observation_size, action_size, members).to(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return WorldModel(observation_size, action_size, hidden, kind, future_inputs, members).to(device)


def remake(model: LearnedModel, seed: int) -> LearnedModel:
    """A fresh model of ``model``'s kind, shape and device, its initial weights drawn from ``seed``."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        fresh: WorldModel | LinearModel = type(model)(**model.settings())  # type: ignore[assignment]
    return fresh.to(model.device)


def fit_model(
    model: LearnedModel,
    buffer: EpisodeBuffer,
    settings: FitSettings,
    seed: int = 0,
    split_seed: int | None = None,
    mirror: Mirror | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[FitReport]:
    """Fit ``model`` in place to ``buffer`` (and the episodes' mirror images, where ``mirror`` gives the task's
    reflection symmetry) by its kind's fitter (``FITTERS``); a report per member. A recurrent model's held-out
    episodes are placed by ``split_seed`` (``drrl.models.fit.split_episodes``), the linear model's drawn from
    ``seed`` at every fit (``drrl.models.linear.split_at_random``). ``progress(updates, most)`` is told as a
    gradient fit goes on."""
    return FITTERS[type(model)](model, buffer, settings, seed, split_seed, mirror, progress)
