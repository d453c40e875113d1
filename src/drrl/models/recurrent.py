"""Recurrent world models (thesis 3.3–3.5): a state-space RNN or an LSTM, unfolded in time with shared weights.

One step of the model reads an observation and an action, updates its hidden state, and predicts the next
observation, the reward and whether the episode ends there::

    x_t     = (normalised o_t, a_t)
    s_t     = tanh(W x_t + B s_{t−1} + b)                                  (3.4, 3.6; one such layer per width)
    y_t     = A s_t + c                                                   (3.7: the read-out A)
    ô_{t+1} = o_t + y_t[obs] · std(Δo),   r̂_{t+1} = y_t[reward],   p̂(end) = sigmoid(y_t[end])

Finite unfolding (3.3.1): :meth:`WorldModel.unfold` copies this step over a window of L steps; the copies share
one set of weights, so back-propagation through the unfolded network sums every copy's gradient into the same W,
B and A (shared-weight back-propagation, 3.5.1). The first ``observed_steps`` steps read observed data (3.8, 3.10).

Overshooting (3.3.2): the window runs m steps past the last observed step, with targets there (3.9, 3.11), so that
the model is trained on m-step predictions, the ones imagination needs.

Dynamical consistency (3.3.3): in that future part the observation input is the model's own previous prediction
(``future_inputs="predictions"``, the default) and the actions come from the data (from the policy when
imagining). ``future_inputs="zeros"`` is the thesis's plain overshooting of 3.5, where the input is set to 0
(the data's mean, in normalised units) and only the actions and the recurrence carry the state forward.

Departures from the thesis, and why
    * Actions are part of every step's input: 3.4–3.11 model an uncontrolled time series, a world model must be
      conditioned on what the agent does. In the overshooting part they keep coming from the data.
    * Every window starts from the zero state s_0 = 0, as imagination does from a real start observation.
    * The model predicts the change o_{t+1} − o_t, scaled by its standard deviation in the data, rather than
      o_{t+1} itself: consecutive observations are close, so the change is the part worth learning, and the
      prediction cannot drift far from the current observation in one step.
    * Biases b and c, which the thesis folds into W (3.2).
    * The LSTM is torch's ``nn.LSTMCell``: input, output and forget gates. The thesis's 3.15–3.21 (Hochreiter and
      Schmidhuber 1997) have no forget gate (3.21 only adds to the cell); the forget gate (Gers et al. 2000) lets
      a cell be reset and is what every LSTM since uses.
    * 3.12–3.13 print the cost as Σ (o_t − y_t), without a square, which is unbounded below and rewards any error
      of one sign. :func:`unfolding_loss` sums the *squared* error over the unfolded steps.
    * The end-of-episode head is trained by the same squared error on its probability (the Brier score).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

MODEL_KINDS = ("rnn", "lstm")
FUTURE_INPUTS = ("predictions", "zeros")


@dataclass(frozen=True)
class Prediction:
    """What a model predicts for each unfolded step t: o_{t+1}, r_{t+1} and P(episode ends at t+1)."""

    observations: torch.Tensor  # (..., o)
    rewards: torch.Tensor  # (...)
    ends: torch.Tensor  # (...) probabilities


class WorldModel(nn.Module):
    """A stacked state-space RNN (``kind="rnn"``, 3.4–3.11) or LSTM (``kind="lstm"``, 3.5.2) world model.

    Args:
        observation_size, action_size: sizes of o_t and a_t.
        hidden: the width of each stacked layer, e.g. (64,) or (64, 64).
        kind: "rnn" (s_t = tanh(W x_t + B s_{t−1} + b)) or "lstm".
        future_inputs: what the overshooting part reads, "predictions" (dynamical consistency) or "zeros".
    """

    def __init__(self, observation_size: int, action_size: int, hidden: Sequence[int] = (64,), kind: str = "rnn",
                 future_inputs: str = "predictions"):
        super().__init__()
        if kind not in MODEL_KINDS:
            raise ValueError(f"unknown model kind {kind!r}; choose one of: {', '.join(MODEL_KINDS)}")
        if future_inputs not in FUTURE_INPUTS:
            raise ValueError(f"unknown future_inputs {future_inputs!r}; choose one of: {', '.join(FUTURE_INPUTS)}")
        hidden = tuple(int(width) for width in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden must hold at least one positive layer width, got {hidden}")
        self.observation_size, self.action_size = observation_size, action_size
        self.hidden, self.kind, self.future_inputs = hidden, kind, future_inputs
        cell = nn.RNNCell if kind == "rnn" else nn.LSTMCell
        widths = (observation_size + action_size, *hidden)
        self.layers = nn.ModuleList(cell(fan_in, fan_out) for fan_in, fan_out in zip(widths[:-1], widths[1:]))
        self.readout = nn.Linear(hidden[-1], observation_size + 2)  # A: change of o, reward, end logit
        # Normalisation, set from the data by set_scales(); buffers, so that state_dict() holds them.
        self.register_buffer("observation_mean", torch.zeros(observation_size))
        self.register_buffer("observation_scale", torch.ones(observation_size))
        self.register_buffer("change_scale", torch.ones(observation_size))
        self.register_buffer("reward_mean", torch.zeros(()))
        self.register_buffer("reward_scale", torch.ones(()))

    def set_scales(self, scales: dict[str, torch.Tensor]) -> None:
        """Copy the data's normalisation (``EpisodeBuffer.scales()``) into the model."""
        for name, value in scales.items():
            getattr(self, name).copy_(value)

    def initial_state(self, batch: int) -> list[torch.Tensor]:
        """Zero hidden states for ``batch`` sequences: [s¹, s², …] for "rnn", [h¹, c¹, h², c², …] for "lstm"."""
        device = self.readout.weight.device
        per_layer = 1 if self.kind == "rnn" else 2
        return [torch.zeros(batch, width, device=device) for width in self.hidden for _ in range(per_layer)]

    def _advance(self, x: torch.Tensor, state: list[torch.Tensor]) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The stacked layers on the network input x = (normalised o_t, a_t): read-out y_t (3.7), new state."""
        new_state = []
        for i, layer in enumerate(self.layers):
            if self.kind == "rnn":
                x = layer(x, state[i])
                new_state.append(x)
            else:
                x, cell = layer(x, (state[2 * i], state[2 * i + 1]))
                new_state += [x, cell]
        return self.readout(x), new_state

    def _next_observation(self, observation: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return observation + y[..., :-2] * self.change_scale

    def _heads(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reward and end probability from read-outs y."""
        return y[..., -2] * self.reward_scale + self.reward_mean, torch.sigmoid(y[..., -1])

    def step(self, observation: torch.Tensor, action: torch.Tensor, state: list[torch.Tensor],
             observed: bool | torch.Tensor = True) -> tuple[Prediction, list[torch.Tensor]]:
        """One unfolded step for a batch: o_t (B, o), a_t (B, a) → prediction of step t+1, new state.

        ``observed`` (a bool, or one per sequence) False marks a step of the overshooting part: with
        ``future_inputs="zeros"`` the network then reads 0 instead of ``observation`` (which is still the base the
        predicted change is added to).
        """
        x = (observation - self.observation_mean) / self.observation_scale
        if self.future_inputs == "zeros" and observed is not True:
            x = x * torch.as_tensor(observed, dtype=x.dtype, device=x.device).reshape(-1, 1)
        y, new_state = self._advance(torch.cat([x, action], dim=-1), state)
        rewards, ends = self._heads(y)
        return Prediction(self._next_observation(observation, y), rewards, ends), new_state

    def unfold(self, observations: torch.Tensor, actions: torch.Tensor, observed_steps: int) -> Prediction:
        """Unfold over windows of L steps: observations o_0..o_{L−1} (B, L, o), actions a_0..a_{L−1} (B, L, a).

        Steps t < ``observed_steps`` read o_t from the data; the later ones are the overshooting part and read the
        model's own prediction ô_t (dynamical consistency), never the data. Returns predictions of o_1..o_L,
        r_1..r_L and the ends, each with the window's shape (B, L, …).

        The same computation as L calls of :meth:`step`, with the per-step work cut to what the recurrence needs
        (the observed inputs are normalised at once, the reward and end heads read the stacked read-outs after
        the loop): fitting spends most of its time here.
        """
        length = actions.shape[1]
        if not 1 <= observed_steps <= length:
            raise ValueError(f"observed_steps must be in [1, {length}] for windows of {length} steps, "
                             f"got {observed_steps}")
        inputs = torch.cat([(observations[:, :observed_steps] - self.observation_mean) / self.observation_scale,
                            actions[:, :observed_steps]], dim=-1)
        state = self.initial_state(actions.shape[0])
        outputs, predicted = [], []
        for t in range(length):
            if t < observed_steps:
                x, base = inputs[:, t], observations[:, t]
            else:
                fed = (base - self.observation_mean) / self.observation_scale
                x = torch.cat([fed if self.future_inputs == "predictions" else torch.zeros_like(fed),
                               actions[:, t]], dim=-1)
            y, state = self._advance(x, state)
            base = self._next_observation(base, y)
            outputs.append(y)
            predicted.append(base)
        rewards, ends = self._heads(torch.stack(outputs, dim=1))
        return Prediction(observations=torch.stack(predicted, dim=1), rewards=rewards, ends=ends)

    def describe(self) -> str:
        layers = "×".join(map(str, self.hidden))
        return f"{self.kind} {layers}, future inputs: {self.future_inputs}"


def unfolding_loss(model: WorldModel, prediction: Prediction, next_observations: torch.Tensor,
                   rewards: torch.Tensor, ends: torch.Tensor, mask: torch.Tensor, learn_reward: bool = True
                   ) -> torch.Tensor:
    """The squared error summed over the unfolded steps (3.12–3.13, squared), averaged over the windows.

    Observation errors are measured in units of the data's per-step change (so a k-step error is comparable to k
    one-step errors), rewards in units of their standard deviation; ``mask`` (B, L) drops steps past an episode's
    end. With ``learn_reward=False`` (the task's reward is known in closed form) the reward and end heads are not
    trained.
    """
    error = ((prediction.observations - next_observations) / model.change_scale).square().sum(-1)
    if learn_reward:
        error = error + ((prediction.rewards - rewards) / model.reward_scale).square()
        error = error + (prediction.ends - ends).square()
    return (error * mask).sum() / mask.shape[0]
