"""Fitting a world model to real episodes: shared-weight back-propagation through the unfolding (3.5.1).

Minibatches of windows go through ``WorldModel.unfold``; the squared error summed over the unfolded steps
(``unfolding_loss``) is minimised by one of the thesis's optimizers (3.5.3: Nesterov's accelerated gradient 3.24,
Adam with λ of Algorithm 4) or torch's own, with the step size decaying along a cosine to 0 over ``max_updates``
(beyond the thesis: the loss is dominated by a few hard windows, e.g. of a falling pole, and a constant step keeps
the fit jumping around). Every fifth episode (at the default ``holdout`` of 0.2) is held out, chosen by its place in
the buffer, so that an episode held out in one fit stays held out in the next as episodes are added: a model fitted
again from its previous weights has then never trained on its held-out episodes, and the held-out losses of
successive fits are comparable. Training stops once their loss has not improved for ``patience`` validations, and
the model keeps the weights of its best validation. With too few episodes to hold any out, the training loss
stands in for the held-out loss in choosing the weights kept, but never stops the fit early: it would stop on the
noise of the minibatches, not on overfitting. The K members of an ensemble are fitted side by side in one batched
network, each on its own split of the episodes: member k's held-out places are shifted by k/K of the period, so that
five members at 0.2 hold out five different fifths (the folds of a cross-validation).

Divergence: a loss that turns NaN or infinite stops the fit at once; the model gets back the weights of its last
good validation and the report says ``stop="diverged"`` (and a warning is issued), so a caller never goes on with a
broken model unknowingly. The data are never touched.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np
import torch

from drrl.models.data import EpisodeBuffer, Mirror, with_mirror_images
from drrl.models.optimizers import AdamLambda, NesterovAG
from drrl.models.recurrent import WorldModel, window_losses

MODEL_OPTIMIZERS = ("adam_lambda", "nag", "adam", "sgd")


REPEATS = 8  # a fit's batch draws at most this many times the training windows it has


@dataclass(frozen=True)
class FitSettings:
    """How a world model is trained.

    unfold: observed steps per window (3.3.1); overshoot: steps past them with targets (3.3.2).
    learn_reward: train the reward and end heads (off when the task's reward is known in closed form).
    optimizer: "adam_lambda" (Algorithm 4, the default), "nag" (3.24), or torch's "adam" or "sgd".
    holdout: fraction of episodes held out for early stopping; validate_every updates; patience validations.
    batch_size: windows drawn a step, at most REPEATS times the training windows (a run's first fits have few).
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
            raise ValueError(
                f"unknown model optimizer {self.optimizer!r}; choose one of: {', '.join(MODEL_OPTIMIZERS)}"
            )
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
    """One of ``MODEL_OPTIMIZERS`` with step size ``lr``."""
    if name == "adam_lambda":
        return AdamLambda(params, lr=lr)
    if name == "nag":
        return NesterovAG(params, lr=lr, momentum=momentum)
    if name == "adam":
        return torch.optim.Adam(params, lr=lr)
    if name == "sgd":
        return torch.optim.SGD(params, lr=lr, momentum=momentum)
    raise ValueError(f"unknown model optimizer {name!r}; choose one of: {', '.join(MODEL_OPTIMIZERS)}")


REPORT_EVERY = 10  # updates between two reports of a fit's progress


def fit(
    model: WorldModel,
    buffer: EpisodeBuffer,
    settings: FitSettings = FitSettings(),
    seed: int = 0,
    split_seed: int | None = None,
    mirror: Mirror | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[FitReport]:
    """Train ``model``'s K members on ``buffer`` in place, side by side, each with its own held-out episodes,
    normalisation and minibatches; returns a report per member. Raises if the data cannot be unfolded.

    ``seed`` draws the minibatches; ``split_seed`` (``seed`` if None) places the held-out episodes
    (``split_episodes``): a run passes the same one to every fit, so that its splits only grow. With ``mirror``, the
    task's reflection symmetry, every episode is also fitted (or held out) as its mirror image, beside itself.

    A member whose validation loss has not improved for ``patience`` validations keeps its best weights; the fit
    stops when every member has, or after ``max_updates``. ``progress(updates, max_updates)`` is told every
    ``REPORT_EVERY`` updates.
    """
    buffer.check_unfolding(settings.unfold, settings.overshoot)
    splits = [split_episodes(buffer, settings, offset) for offset in split_offsets(split_seed, seed, len(model))]
    held_out_episodes = [len(held_out) for _, held_out in splits]  # real episodes, not their images
    if mirror is not None:
        buffer, *parts = with_mirror_images([buffer, *(part for split in splits for part in split)], mirror)
        splits = list(zip(parts[::2], parts[1::2], strict=True))
    scales = [training.scales() for training, _ in splits]
    model.set_scales({name: torch.stack([member[name] for member in scales]) for name in scales[0]})
    windows = buffer.windows(settings.unfold, settings.overshoot).to(model.device)
    episode_of_window = buffer.window_episodes(settings.unfold)
    train_index, train_weight = _member_windows([training for training, _ in splits], buffer, episode_of_window)
    valid_index, valid_weight = _member_windows(
        [held_out if len(held_out) else training for training, held_out in splits], buffer, episode_of_window
    )
    train_counts = train_weight.sum(1)
    may_stop_early = all(len(held_out) for _, held_out in splits)
    generator = torch.Generator().manual_seed(seed)
    parameters = list(model.parameters())
    optimizer = make_model_optimizer(settings.optimizer, parameters, settings.lr, settings.momentum)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.max_updates)

    def losses_of(index: torch.Tensor) -> torch.Tensor:
        batch = windows.select(index.to(model.device))
        prediction = model.unfold(batch.observations, batch.actions, settings.unfold)
        return window_losses(
            model, prediction, batch.next_observations, batch.rewards, batch.ends, batch.mask, settings.learn_reward
        )

    def validation_losses() -> torch.Tensor:
        with torch.no_grad():
            return (losses_of(valid_index) * valid_weight).sum(-1) / valid_weight.sum(-1)

    best_loss = validation_losses()
    best_state = [p.detach().clone() for p in parameters]
    since_best = torch.zeros(len(model), dtype=torch.long)
    stop, updates = "max_updates", 0
    batch_size = min(settings.batch_size, REPEATS * int(train_counts.max()))  # more draws only repeat windows
    for updates in range(1, settings.max_updates + 1):
        positions = (torch.rand(len(model), batch_size, generator=generator) * train_counts[:, None]).long()
        index = train_index.gather(1, positions)

        def closure(index=index):
            optimizer.zero_grad()
            loss = losses_of(index).mean(-1)  # (K,): the members are independent, so their sum trains each alone
            loss.sum().backward()
            if settings.max_grad_norm is not None:
                clip_member_gradients(parameters, settings.max_grad_norm)
            return loss

        loss = cast(torch.Tensor, optimizer.step(closure))  # what the closure returned
        schedule.step()
        if not torch.isfinite(loss).all():
            stop = "diverged"
            break
        if progress is not None and updates % REPORT_EVERY == 0:
            progress(updates, settings.max_updates)
        if updates % settings.validate_every == 0:
            current = validation_losses()
            if not torch.isfinite(current).all():
                stop = "diverged"
                break
            improved = current < best_loss
            best_loss = torch.where(improved, current, best_loss)
            for kept, p in zip(best_state, parameters, strict=True):
                kept[improved] = p.detach()[improved]
            since_best = torch.where(improved, 0, since_best + 1)
            if may_stop_early and (since_best >= settings.patience).all():
                stop = "patience"
                break
    with torch.no_grad():
        for kept, p in zip(best_state, parameters, strict=True):
            p.copy_(kept)
    if stop == "diverged":
        warnings.warn(
            f"world model diverged (non-finite loss) after {updates} updates; kept the weights of its "
            f"last good validation (losses {best_loss.tolist()})",
            RuntimeWarning,
            stacklevel=2,
        )
    with torch.no_grad():
        train_loss = (losses_of(train_index) * train_weight).sum(-1) / train_counts
    return [
        FitReport(
            updates=updates,
            train_loss=float(train_loss[k]),
            valid_loss=float(best_loss[k]),
            held_out_episodes=held_out_episodes[k],
            stop=stop,
        )
        for k in range(len(model))
    ]


def clip_member_gradients(parameters: list[torch.Tensor], max_norm: float) -> None:
    """Gradient norm clipping (as ``torch.nn.utils.clip_grad_norm_``) for each member apart: every parameter's
    leading dimension is the member."""
    grads = [p.grad for p in parameters if p.grad is not None]
    norms = torch.stack([g.flatten(1).square().sum(1) for g in grads]).sum(0).sqrt()  # (K,)
    factor = (max_norm / (norms + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(factor.reshape(-1, *[1] * (g.dim() - 1)))


def _member_windows(
    parts: list[EpisodeBuffer], buffer: EpisodeBuffer, episode_of_window: np.ndarray
) -> tuple[torch.Tensor, torch.Tensor]:
    """For each member, the windows of its part of ``buffer``'s episodes: (K, M) window indices padded with the
    first, and (K, M) weights, 1 for a window of the part and 0 for padding."""
    position = {id(episode): i for i, episode in enumerate(buffer.episodes)}
    chosen = [np.flatnonzero(np.isin(episode_of_window, [position[id(e)] for e in part.episodes])) for part in parts]
    width = max(len(c) for c in chosen)
    index = torch.zeros(len(parts), width, dtype=torch.long)
    weight = torch.zeros(len(parts), width)
    for k, c in enumerate(chosen):
        index[k, : len(c)] = torch.as_tensor(c)
        index[k, len(c) :] = int(c[0])
        weight[k, : len(c)] = 1.0
    return index, weight


def split_offsets(split_seed: int | None, seed: int, members: int) -> list[float]:
    """The place of each of ``members`` members' held-out episodes within the period 1 / holdout, as a fraction of
    it in [0, 1): one drawn from ``split_seed`` (``seed`` if None), shifted by k / K for member k."""
    start = np.random.default_rng(seed if split_seed is None else split_seed).random()
    return [(start + k / members) % 1.0 for k in range(members)]


def split_episodes(buffer: EpisodeBuffer, settings: FitSettings, offset: float) -> tuple[EpisodeBuffer, EpisodeBuffer]:
    """Hold out one episode in every 1 / ``settings.holdout`` by its place i in the buffer, from ``offset``: episode
    i where ⌊(i + 1 + offset / h)·h⌋ > ⌊(i + offset / h)·h⌋, h the holdout fraction (systematic sampling; 0.2
    holds out every fifth). Episode i's place never changes as episodes are added, so neither does its part.

    Episodes too short to unfold stay in training, and so does the longest unless one as long is trained on (training
    keeps a full window). With too few episodes (⌊h · E⌋ = 0, fewer than 5 at the default) nothing is held out: the
    first real episodes are too precious to set aside, and the training loss stands in for the validation loss.
    """
    h = settings.holdout
    if int(h * len(buffer)) == 0:
        return buffer, EpisodeBuffer()
    place = np.arange(len(buffer)) + offset / h
    lengths = np.array([len(episode) for episode in buffer.episodes])
    held = (np.floor((place + 1) * h) > np.floor(place * h)) & (lengths >= settings.unfold)
    if not (lengths[~held] == lengths.max()).any():  # the longest held out, and none as long left to train on
        held[np.argmax(np.where(held, lengths, -1))] = False
    return (
        EpisodeBuffer([e for e, out in zip(buffer.episodes, held, strict=True) if not out]),
        EpisodeBuffer([e for e, out in zip(buffer.episodes, held, strict=True) if out]),
    )
