"""Fitting a world model to real episodes: shared-weight back-propagation through the unfolding (3.5.1).

Minibatches of windows go through :meth:`WorldModel.unfold`; the squared error summed over the unfolded steps
(:func:`unfolding_loss`) is minimised by one of the thesis's optimizers (3.5.3: Nesterov's accelerated gradient 3.24,
Adam with λ of Algorithm 4) or torch's own, with the step size decaying along a cosine to 0 over ``max_updates``
(beyond the thesis: the loss is dominated by a few hard windows, e.g. of a falling pole, and a constant step keeps
the fit jumping around). A random part of the episodes is held out; training stops once their loss has not improved
for ``patience`` validations, and the model keeps the weights of its best validation.

Divergence: a loss that turns NaN or infinite stops the fit at once; the model gets back the weights of its last
good validation and the report says ``stop="diverged"`` (and a warning is issued), so a caller never goes on with a
broken model unknowingly. The data are never touched.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from drrl.models.data import EpisodeBuffer, Windows
from drrl.models.recurrent import WorldModel, unfolding_loss
from drrl.search.optimizers import AdamLambda, NesterovAG

MODEL_OPTIMIZERS = ("adam_lambda", "nag", "adam", "sgd")


@dataclass(frozen=True)
class FitSettings:
    """How a world model is trained.

    unfold: observed steps per window (3.3.1); overshoot: steps past them with targets (3.3.2).
    learn_reward: train the reward and end heads (off when the task's reward is known in closed form).
    optimizer: "adam_lambda" (Algorithm 4, the default), "nag" (3.24), or torch's "adam" or "sgd".
    holdout: fraction of episodes held out for early stopping; validate_every updates; patience validations.
    max_grad_norm: gradient norm clipping against exploding gradients (3.5.2); None for none.
    """

    unfold: int = 4
    overshoot: int = 16
    learn_reward: bool = True
    optimizer: str = "adam_lambda"
    lr: float = 1e-2  # the start of a cosine decay to 0 over max_updates
    momentum: float = 0.9  # for "nag" and "sgd"
    batch_size: int = 64
    max_updates: int = 1000
    validate_every: int = 100
    patience: int = 5
    holdout: float = 0.2
    max_grad_norm: float | None = 10.0

    def __post_init__(self):
        if self.optimizer not in MODEL_OPTIMIZERS:
            raise ValueError(f"unknown model optimizer {self.optimizer!r}; choose one of: "
                             f"{', '.join(MODEL_OPTIMIZERS)}")
        if self.unfold < 1 or self.overshoot < 0:
            raise ValueError(f"unfold must be >= 1 and overshoot >= 0, got {self.unfold} and {self.overshoot}")
        for name in ("batch_size", "max_updates", "validate_every", "patience"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive finite number, got {self.lr}")
        if not 0 <= self.holdout < 1:
            raise ValueError(f"holdout must be in [0, 1), got {self.holdout}")


@dataclass(frozen=True)
class FitReport:
    updates: int  # gradient steps taken
    train_loss: float  # loss per training window, at the kept weights
    valid_loss: float  # loss per held-out window, at the kept weights (the training loss if nothing was held out)
    held_out_episodes: int
    stop: str  # "patience", "max_updates" or "diverged"


def make_model_optimizer(name: str, params, lr: float, momentum: float = 0.9) -> torch.optim.Optimizer:
    """One of :data:`MODEL_OPTIMIZERS` with step size ``lr``."""
    if name == "adam_lambda":
        return AdamLambda(params, lr=lr)
    if name == "nag":
        return NesterovAG(params, lr=lr, momentum=momentum)
    if name == "adam":
        return torch.optim.Adam(params, lr=lr)
    if name == "sgd":
        return torch.optim.SGD(params, lr=lr, momentum=momentum)
    raise ValueError(f"unknown model optimizer {name!r}; choose one of: {', '.join(MODEL_OPTIMIZERS)}")


def fit(model: WorldModel, buffer: EpisodeBuffer, settings: FitSettings = FitSettings(), seed: int = 0
        ) -> FitReport:
    """Train ``model`` on ``buffer`` in place; returns what happened. Raises if the data cannot be unfolded."""
    buffer.check_unfolding(settings.unfold, settings.overshoot)
    training, held_out = _split(buffer, settings, np.random.default_rng(seed))
    model.set_scales(training.scales())
    device = model.readout.weight.device
    train_windows = training.windows(settings.unfold, settings.overshoot).to(device)
    valid_windows = held_out.windows(settings.unfold, settings.overshoot).to(device) if len(held_out) else None
    generator = torch.Generator().manual_seed(seed)
    optimizer = make_model_optimizer(settings.optimizer, model.parameters(), settings.lr, settings.momentum)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.max_updates)

    def loss_of(windows: Windows) -> torch.Tensor:
        prediction = model.unfold(windows.observations, windows.actions, settings.unfold)
        return unfolding_loss(model, prediction, windows.next_observations, windows.rewards, windows.ends,
                              windows.mask, settings.learn_reward)

    def validation_loss() -> float:
        with torch.no_grad():
            return float(loss_of(valid_windows if valid_windows is not None else train_windows))

    best_loss, best_state = validation_loss(), copy.deepcopy(model.state_dict())
    since_best, stop, updates = 0, "max_updates", 0
    for updates in range(1, settings.max_updates + 1):
        index = torch.randint(len(train_windows), (settings.batch_size,), generator=generator).to(device)
        batch = train_windows.select(index)

        def closure():
            optimizer.zero_grad()
            loss = loss_of(batch)
            loss.backward()
            if settings.max_grad_norm is not None:
                torch.nn.utils.clip_grad_norm_(model.parameters(), settings.max_grad_norm)
            return loss

        loss = optimizer.step(closure)
        schedule.step()
        if not torch.isfinite(loss):
            stop = "diverged"
            break
        if updates % settings.validate_every == 0:
            current = validation_loss()
            if not math.isfinite(current):
                stop = "diverged"
                break
            if current < best_loss:
                best_loss, best_state, since_best = current, copy.deepcopy(model.state_dict()), 0
            else:
                since_best += 1
                if since_best >= settings.patience:
                    stop = "patience"
                    break
    model.load_state_dict(best_state)
    if stop == "diverged":
        warnings.warn(f"world model diverged (non-finite loss) after {updates} updates; kept the weights of its "
                      f"last good validation (loss {best_loss:.4g})", RuntimeWarning, stacklevel=2)
    with torch.no_grad():
        train_loss = float(loss_of(train_windows))
    return FitReport(updates=updates, train_loss=train_loss, valid_loss=best_loss,
                     held_out_episodes=len(held_out), stop=stop)


def _split(buffer: EpisodeBuffer, settings: FitSettings, rng: np.random.Generator
           ) -> tuple[EpisodeBuffer, EpisodeBuffer]:
    """Hold out ⌊holdout · E⌋ of the E episodes, among those that can be unfolded and never the longest (training
    keeps a full window).

    With too few episodes for that (fewer than 5 at the default 0.2) nothing is held out: the first real episodes
    are too precious to set aside, and the training loss stands in for the validation loss.
    """
    eligible = [e for e in buffer.episodes if len(e) >= settings.unfold]
    longest = max(buffer.episodes, key=len)
    candidates = [e for e in eligible if e is not longest]
    count = min(len(candidates), int(settings.holdout * len(buffer)))
    if count == 0:
        return buffer, EpisodeBuffer()
    chosen = {id(candidates[i]) for i in rng.permutation(len(candidates))[:count]}
    return (EpisodeBuffer([e for e in buffer.episodes if id(e) not in chosen]),
            EpisodeBuffer([e for e in buffer.episodes if id(e) in chosen]))
