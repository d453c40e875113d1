"""A linear world model fitted in closed form: the state-space model of thesis 3.3 with the identity as activation.

One step reads the observation, the action and the previous action, and predicts the next observation's change,
the reward and the end linearly::

    x_t     = (normalised o_t, normalised a_t, normalised a_{t−1}, 1)        (a_{−1} = 0: no command yet)
    y_t     = x_t W                                                          (W: (f, o + 2), one per member)
    ô_{t+1} = o_t + y_t[obs] · std(Δo),   r̂_{t+1} = y_t[reward] · std(r) + mean(r),   p̂(end) = clip(y_t[end], 0, 1)

Its memory, the state carried from step to step, is the previous action: enough for a command that acts a control
period late, as a real robot's does (``drrl.envs.baxter.standin``).

Why a linear model. A recurrent network generalises from the data it was fitted on, and a model-based run's
first data are few and narrow: on Baxter they are episodes of perturbed policies that drive a joint into its stop
within seconds, and an RNN fitted on them mispredicts the gentle motions of a reach by tens of per-step changes
within half a second (BENCHMARKS.md), so no search inside it finds the reach. A joint under a velocity servo follows
its command almost linearly wherever the arm is, so a linear model fitted on those episodes stays near enough on a
reach for the search to find it (one arm: 10 of 10 seeds, BENCHMARKS.md). Where the dynamics are strongly
nonlinear (the cart-pole's pole) the recurrent models of ``drrl.models.recurrent`` are the ones to use.

Fitting (``fit_linear``) is ridge regression of the one-step targets on the features, exact and instant, where
the recurrent models need thousands of gradient steps; each member of an ensemble is fitted on its own episodes.
A run started from another's model (``start_from``) identifies it again from its own episodes: a few hundred steps
pin its weights down, where a recurrent model is fine-tuned from the weights it was given.

Departures from the thesis, and why
    * 3.3's state-space model feeds its own state back through a nonlinearity and reads the observation off it;
      here the state is the observed o_t itself plus the last action (a linear ARX model, the textbook model of
      system identification), so that least squares fits it in one solve rather than by back-propagation through
      time. Overshooting and dynamical consistency (3.3.2–3.3.3) need no training here: the model is fitted on
      one-step errors and then, as every model, fed its own predictions when imagining; its k-step errors are
      measured the same way (``drrl.models.quality``).
    * The end is a linear probability, clipped to [0, 1], rather than a sigmoid's.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from torch import nn

from drrl.models.base import Prediction, per_member, spread
from drrl.models.data import EpisodeBuffer, Mirror, with_mirror_images
from drrl.models.fit import FitReport, FitSettings
from drrl.models.recurrent import window_losses

RIDGE = 1e-3  # λ of the ridge, per training step: keeps constant and collinear features (fixed targets) harmless


class LinearModel(nn.Module):
    """K linear world models (module docstring), stepped as one.

    Args:
        observation_size: the size of o_t.
        action_size: the size of a_t.
        members: K, the ensemble's size; every output has a leading dimension K.
    """

    # buffers, per member: the data's scales (K, o) or (K,) and the fitted weights
    observation_mean: torch.Tensor
    observation_scale: torch.Tensor
    change_scale: torch.Tensor
    reward_mean: torch.Tensor
    reward_scale: torch.Tensor
    action_mean: torch.Tensor
    action_scale: torch.Tensor
    weight: torch.Tensor
    ridge = RIDGE

    def __init__(self, observation_size: int, action_size: int, members: int = 1):
        super().__init__()
        if members < 1:
            raise ValueError(f"a world model needs at least one member, got members={members}")
        self.observation_size, self.action_size, self.members = observation_size, action_size, members
        self.register_buffer("observation_mean", torch.zeros(members, observation_size))
        self.register_buffer("observation_scale", torch.ones(members, observation_size))
        self.register_buffer("change_scale", torch.ones(members, observation_size))
        self.register_buffer("reward_mean", torch.zeros(members))
        self.register_buffer("reward_scale", torch.ones(members))
        self.register_buffer("action_mean", torch.zeros(members, action_size))
        self.register_buffer("action_scale", torch.ones(members, action_size))
        self.register_buffer("weight", torch.zeros(members, self.num_features, observation_size + 2))

    @property
    def num_features(self) -> int:
        return self.observation_size + 2 * self.action_size + 1

    def __len__(self) -> int:
        return self.members

    def settings(self) -> dict:
        """The constructor's arguments: ``LinearModel(**model.settings())`` builds a model of the same shape."""
        return {"observation_size": self.observation_size, "action_size": self.action_size, "members": self.members}

    @property
    def device(self) -> torch.device:
        return self.weight.device

    def initial_state(self, batch: int) -> list[torch.Tensor]:
        """The previous action of ``batch`` new episodes, (K, batch, a): zero, no command yet (as a restarted
        imagined episode's state is set)."""
        return [torch.zeros(self.members, batch, self.action_size, device=self.device)]

    def features(self, observation: torch.Tensor, action: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """x_t (K, …, f) of o_t, a_t and a_{t−1}, each (K, …, ·)."""
        return torch.cat(
            [
                (observation - per_member(self.observation_mean, observation))
                / per_member(self.observation_scale, observation),
                (action - per_member(self.action_mean, action)) / per_member(self.action_scale, action),
                (previous - per_member(self.action_mean, previous)) / per_member(self.action_scale, previous),
                torch.ones_like(observation[..., :1]),
            ],
            dim=-1,
        )

    def step(
        self,
        observation: torch.Tensor,
        action: torch.Tensor,
        state: list[torch.Tensor],
        observed: bool | torch.Tensor = True,
    ) -> tuple[Prediction, list[torch.Tensor]]:
        """Every member's prediction of step t+1 (K, B, ·) from o_t (B, o) and a_t (B, a), read by every member, or
        (K, B, ·) each its own; the new state (this action). ``observed`` does not matter to a linear model."""
        observation, action = self._per_member_inputs(observation), self._per_member_inputs(action)
        y = torch.bmm(self.features(observation, action, state[0]), self.weight)
        return self._prediction(observation, y), [action.contiguous()]  # a copy where action is expanded

    def unfold(
        self,
        observations: torch.Tensor,
        actions: torch.Tensor,
        observed_steps: int,
        previous_actions: torch.Tensor | None = None,
    ) -> Prediction:
        """Windows of L steps (B, L, ·) or (K, B, L, ·), as ``WorldModel.unfold``: steps before ``observed_steps``
        read the data's o_t, later ones the model's own prediction. The memory starts from ``previous_actions``
        (B, a), the action before each window (``Windows.previous_actions``), or zero."""
        if observations.dim() == 3:
            observations = observations.expand(self.members, *observations.shape)
            actions = actions.expand(self.members, *actions.shape)
        state = self.initial_state(actions.shape[1])
        if previous_actions is not None:
            state = [self._per_member_inputs(previous_actions)]
        predictions = []
        base = observations[:, :, 0]
        for t in range(actions.shape[2]):
            if t < observed_steps:
                base = observations[:, :, t]
            prediction, state = self.step(base, actions[:, :, t], state)
            base = prediction.observations
            predictions.append(prediction)
        fields = ("observations", "rewards", "ends")
        return Prediction(*(torch.stack([getattr(p, name) for p in predictions], dim=2) for name in fields))

    def disagreement(self, prediction: Prediction) -> torch.Tensor:
        """(B,) the members' spread, as ``WorldModel.disagreement``; 0 for a single member."""
        return spread(prediction, self.change_scale)

    def describe(self) -> str:
        return f"linear, previous action as memory, {self.members} member(s)"

    def _prediction(self, observation: torch.Tensor, y: torch.Tensor) -> Prediction:
        change = y[..., :-2] * per_member(self.change_scale, observation)
        reward = y[..., -2] * per_member(self.reward_scale, y[..., -2]) + per_member(self.reward_mean, y[..., -2])
        return Prediction(observation + change, reward, y[..., -1].clamp(0.0, 1.0))

    def solve(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The weight W (f, o + 2) that minimises ‖xW − y‖² + ridge · n · ‖W‖² over the n rows of x (n, f)."""
        gram = x.T @ x + self.ridge * len(x) * torch.eye(x.shape[1], dtype=x.dtype, device=x.device)
        return torch.linalg.solve(gram, x.T @ y)

    def _per_member_inputs(self, tensor: torch.Tensor) -> torch.Tensor:
        return tensor.expand(self.members, *tensor.shape) if tensor.dim() == 2 else tensor


def fit_linear(
    model: LinearModel,
    buffer: EpisodeBuffer,
    settings: FitSettings = FitSettings(),
    seed: int = 0,
    mirror: Mirror | None = None,
) -> list[FitReport]:
    """Fit each member of ``model`` in place by ridge regression on its own training episodes (``split_at_random``),
    with their mirror images where ``mirror`` gives the task's reflection symmetry; a report per member, its losses
    measured as the recurrent models' are (``window_losses`` over windows of ``settings.unfold`` +
    ``settings.overshoot`` steps)."""
    buffer.check_unfolding(settings.unfold, settings.overshoot)
    rng = np.random.default_rng(seed)
    reports = []
    for k in range(len(model)):
        training, held_out = split_at_random(buffer, settings, rng)
        real_held_out = len(held_out)
        if mirror is not None:
            training, held_out = with_mirror_images([training, held_out], mirror)
        _fit_member(model, k, training, settings.learn_reward)
        reports.append((training, held_out, real_held_out))
    return [
        FitReport(
            updates=0,
            train_loss=_loss(model, k, training, settings),
            valid_loss=_loss(model, k, held_out if len(held_out) else training, settings),
            held_out_episodes=real_held_out,
            stop="least_squares",
        )
        for k, (training, held_out, real_held_out) in enumerate(reports)
    ]


def _fit_member(model: LinearModel, k: int, training: EpisodeBuffer, learn_reward: bool) -> None:
    scales = training.scales()
    actions = np.concatenate([episode.actions for episode in training.episodes])
    scales["action_mean"] = torch.as_tensor(actions.mean(0))
    scales["action_scale"] = torch.as_tensor(np.where(actions.std(0) > 1e-6, actions.std(0), 1.0).astype(np.float32))
    with torch.no_grad():
        for name, value in scales.items():
            getattr(model, name)[k] = value.to(model.device)
    observations, current, previous, targets = [], [], [], []
    for episode in training.episodes:
        observations.append(episode.observations[:-1])
        current.append(episode.actions)
        previous.append(np.concatenate([np.zeros_like(episode.actions[:1]), episode.actions[:-1]]))
        targets.append(
            np.column_stack(
                [
                    np.diff(episode.observations, axis=0) / scales["change_scale"].numpy(),
                    (episode.rewards - scales["reward_mean"].numpy()) / scales["reward_scale"].numpy(),
                    episode.ends(),
                ]
            )
        )
    member = slice(k, k + 1)
    x = (
        _member_view(model, member)
        .features(
            *(
                torch.as_tensor(np.concatenate(part))[None].to(model.device)
                for part in (observations, current, previous)
            )
        )[0]
        .double()
    )
    y = torch.as_tensor(np.concatenate(targets), dtype=torch.float64, device=model.device)
    weight = model.solve(x, y)
    if not learn_reward:
        weight[:, -2:] = 0.0
    with torch.no_grad():
        model.weight[k] = weight.to(model.weight.dtype)


def _member_view(model: LinearModel, member: slice) -> LinearModel:
    """A one-member model of ``model``'s kind sharing its buffers for ``member``."""
    view = copy.copy(model)
    view._buffers = {name: value[member] for name, value in model.named_buffers()}
    view.members = 1
    return view


def _loss(model: LinearModel, k: int, episodes: EpisodeBuffer, settings: FitSettings) -> float:
    """Member k's mean window loss on ``episodes`` (``window_losses``)."""
    view = _member_view(model, slice(k, k + 1))
    windows = episodes.windows(settings.unfold, settings.overshoot).to(model.device)
    with torch.no_grad():
        prediction = view.unfold(windows.observations, windows.actions, settings.unfold, windows.previous_actions)
        losses = window_losses(
            view,  # type: ignore[arg-type]  # the same scales as a WorldModel
            prediction,
            windows.next_observations,
            windows.rewards,
            windows.ends,
            windows.mask,
            settings.learn_reward,
        )
    return float(losses.mean())


def split_at_random(
    buffer: EpisodeBuffer, settings: FitSettings, rng: np.random.Generator
) -> tuple[EpisodeBuffer, EpisodeBuffer]:
    """Hold out ⌊holdout · E⌋ of the E episodes drawn at random, among those that can be unfolded and never the
    longest (training keeps a full window); none while that is 0 (fewer than 5 episodes at the default 0.2).

    Drawn afresh at every fit, where the recurrent models hold out the same places at every fit of a run
    (``drrl.models.fit.split_episodes``): a least-squares fit starts from nothing, so it has never seen the episodes
    it holds out whichever they are. Kept so because Baxter's reach, the linear model's task, was measured with it
    (with fixed places, one of the seven seeds measured never reached the target in 30 real episodes; all ten had).
    """
    eligible = [e for e in buffer.episodes if len(e) >= settings.unfold]
    longest = max(buffer.episodes, key=len)
    candidates = [e for e in eligible if e is not longest]
    count = min(len(candidates), int(settings.holdout * len(buffer)))
    if count == 0:
        return buffer, EpisodeBuffer()
    chosen = {id(candidates[i]) for i in rng.permutation(len(candidates))[:count]}
    return (
        EpisodeBuffer([e for e in buffer.episodes if id(e) not in chosen]),
        EpisodeBuffer([e for e in buffer.episodes if id(e) in chosen]),
    )
