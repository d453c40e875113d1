"""Recurrent world models (thesis 3.3–3.5): a state-space RNN or an LSTM, unfolded in time with shared weights.

One step of the model reads an observation and an action, updates its hidden state, and predicts the next
observation, the reward and whether the episode ends there::

    x_t     = (normalised o_t, a_t)
    s_t     = tanh(W x_t + B s_{t−1} + b)                                  (3.4, 3.6; one such layer per width)
    y_t     = A s_t + c                                                   (3.7: the read-out A)
    ô_{t+1} = o_t + y_t[obs] · std(Δo),   r̂_{t+1} = y_t[reward],   p̂(end) = sigmoid(y_t[end])

Finite unfolding (3.3.1): ``WorldModel.unfold`` copies this step over a window of L steps; the copies share
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
    * The LSTM has input, output and forget gates, in the order of torch's ``nn.LSTMCell``. The thesis's
      3.15–3.21 (Hochreiter and Schmidhuber 1997) have no forget gate (3.21 only adds to the cell); the forget gate
      (Gers et al. 2000) lets a cell be reset and is what every LSTM since uses. The state-space layers step with
      the Elman policies' cell; the LSTM keeps a cell of its own, because the LSTM policies' orders its gates
      (i, f, o, g) and rounds its update by ``addcmul``: one shared cell would change the numbers of either the
      world models' or the LSTM policies' measured runs.
    * 3.12–3.13 print the cost as Σ (o_t − y_t), without a square, which is unbounded below and rewards any error
      of one sign. ``unfolding_loss`` sums the *squared* error over the unfolded steps.
    * The end-of-episode head is trained by the same squared error on its probability (the Brier score).

A feed-forward kind (``kind="mlp"``, beyond the thesis): the same layers with B = 0 and no state, so each step
reads o_t and a_t alone, the one-step networks of model-based RL since PETS (Chua et al. 2018). Where the observation
is the whole state (the swing-up's (s, ṡ, sin θ, cos θ, θ̇)) it needs no memory, and a step costs a matrix product
and a tanh per layer where the LSTM's costs four gates; it is fitted as the others, on unfolded windows with
overshooting, so it is trained on the multi-step predictions imagination makes. Measured on the swing-up and Pendulum,
it is faster and learns less from the same real episodes than the recurrent kinds (BENCHMARKS.md); partially
observed tasks need those.

An ensemble of K members (beyond the thesis, against the "curse of model uncertainty" it names in 2.3) is one
network with a leading member dimension on every weight, stepped by batched matrix products: K small models cost
about what one does, where a loop over them would pay K times the per-step overhead that dominates at these sizes.
The members start from different weights and are fitted on different held-out splits (``drrl.models.fit``), so they
agree where the data pin the dynamics down and disagree where the data are thin. Imagination draws a member per
episode (``drrl.models.imagined``). K = 1 is the thesis's single model.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence

import torch
from torch import nn

from drrl.models.base import Prediction, per_member, spread
from drrl.policies.recurrent import elman_cell

MODEL_KINDS = ("rnn", "lstm")  # the recurrent kinds: a memory the policy can read (drrl.models.remembering)
NETWORK_KINDS = (*MODEL_KINDS, "mlp")  # "mlp": the same layers without the recurrence
FUTURE_INPUTS = ("predictions", "zeros")
GATES = {"rnn": 1, "lstm": 4, "mlp": 1}  # blocks of pre-activations per layer: the state, or the LSTM's i, f, g, o
MEMORIES = {"rnn": 1, "lstm": 2, "mlp": 0}  # state tensors per layer: s, or the LSTM's h and c; none
# a layer's input weights W, recurrent weights B (None in a layer without memory), bias b
Layer = tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]


def _lstm_cell(
    pre_activation: torch.Tensor, memory: tuple[torch.Tensor, torch.Tensor]
) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """An LSTM layer from its pre-activation (gates i, f, g, o, as nn.LSTMCell) and memory (h, c): (h, (h, c))."""
    input_gate, forget_gate, cell_input, output_gate = pre_activation.chunk(4, dim=-1)
    cell = torch.sigmoid(forget_gate) * memory[1] + torch.sigmoid(input_gate) * torch.tanh(cell_input)
    hidden = torch.sigmoid(output_gate) * torch.tanh(cell)
    return hidden, (hidden, cell)


def _feed_forward_cell(pre_activation: torch.Tensor, memory: tuple) -> tuple[torch.Tensor, tuple]:
    """A layer without memory: tanh of its pre-activation."""
    return torch.tanh(pre_activation), ()


CELLS: dict[str, Callable] = {"rnn": elman_cell, "lstm": _lstm_cell, "mlp": _feed_forward_cell}


class WorldModel(nn.Module):
    """K stacked state-space RNNs (``kind="rnn"``, 3.4–3.11), LSTMs (``kind="lstm"``, 3.5.2) or feed-forward tanh
    networks (``kind="mlp"``), stepped as one.

    Args:
        observation_size: the size of o_t.
        action_size: the size of a_t.
        hidden: the width of each stacked layer, e.g. (64,) or (64, 64).
        kind: "rnn" (s_t = tanh(W x_t + B s_{t−1} + b)), "lstm", or "mlp" (s_t = tanh(W x_t + b), no memory).
        future_inputs: what the overshooting part reads, "predictions" (dynamical consistency) or "zeros".
        members: K, the ensemble's size; every output has a leading dimension K.
    """

    # buffers: the data's scales, per member (K, o) or (K,), set by ``set_scales``
    observation_mean: torch.Tensor
    observation_scale: torch.Tensor
    change_scale: torch.Tensor
    reward_mean: torch.Tensor
    reward_scale: torch.Tensor

    def __init__(
        self,
        observation_size: int,
        action_size: int,
        hidden: Sequence[int] = (64,),
        kind: str = "rnn",
        future_inputs: str = "predictions",
        members: int = 1,
    ):
        super().__init__()
        if kind not in NETWORK_KINDS:
            raise ValueError(f"unknown model kind {kind!r}; choose one of: {', '.join(NETWORK_KINDS)}")
        if future_inputs not in FUTURE_INPUTS:
            raise ValueError(f"unknown future_inputs {future_inputs!r}; choose one of: {', '.join(FUTURE_INPUTS)}")
        hidden = tuple(int(width) for width in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden must hold at least one positive layer width, got {hidden}")
        if members < 1:
            raise ValueError(f"a world model needs at least one member, got members={members}")
        self.observation_size, self.action_size = observation_size, action_size
        self.hidden, self.kind, self.future_inputs, self.members = hidden, kind, future_inputs, members
        widths = (observation_size + action_size, *hidden)
        gates = GATES[kind]
        # W, B and b of every layer (3.4), and the read-out A, c (3.7); torch's initialisation, U(±1/√width)
        self.input_weights = nn.ParameterList(
            _uniform(members, fan_in, gates * width, width) for fan_in, width in itertools.pairwise(widths)
        )
        self.recurrent_weights = nn.ParameterList(
            _uniform(members, width, gates * width, width) for width in hidden if MEMORIES[kind]
        )
        self.biases = nn.ParameterList(_uniform(members, 1, gates * width, width) for width in hidden)
        self.readout_weight = _uniform(members, hidden[-1], observation_size + 2, hidden[-1])  # change, reward, end
        self.readout_bias = _uniform(members, 1, observation_size + 2, hidden[-1])
        # Normalisation per member, set from the data by set_scales(); buffers, so that state_dict() holds them.
        self.register_buffer("observation_mean", torch.zeros(members, observation_size))
        self.register_buffer("observation_scale", torch.ones(members, observation_size))
        self.register_buffer("change_scale", torch.ones(members, observation_size))
        self.register_buffer("reward_mean", torch.zeros(members))
        self.register_buffer("reward_scale", torch.ones(members))

    def __len__(self) -> int:
        return self.members

    def settings(self) -> dict:
        """The constructor's arguments: ``WorldModel(**model.settings())`` builds a model of the same shape."""
        return {
            "observation_size": self.observation_size,
            "action_size": self.action_size,
            "hidden": self.hidden,
            "kind": self.kind,
            "future_inputs": self.future_inputs,
            "members": self.members,
        }

    @property
    def device(self) -> torch.device:
        return self.readout_weight.device

    def set_scales(self, scales: dict[str, torch.Tensor]) -> None:
        """Copy the data's normalisation (``EpisodeBuffer.scales()``, or such tensors stacked per member)."""
        for name, value in scales.items():
            getattr(self, name).copy_(value)

    def initial_state(self, batch: int) -> list[torch.Tensor]:
        """Zero hidden states (K, batch, width): [s¹, s², …] for "rnn", [h¹, c¹, h², c², …] for "lstm", [] for
        "mlp"."""
        per_layer = MEMORIES[self.kind]
        return [
            torch.zeros(self.members, batch, width, device=self.device)
            for width in self.hidden
            for _ in range(per_layer)
        ]

    def memory(self, state: list[torch.Tensor]) -> torch.Tensor:
        """(K, B, hidden[-1]) the last layer's hidden state in ``state``: what the model remembers of the steps so
        far, the h that World Models' controller reads beside the observation (``drrl.models.remembering``)."""
        return state[-1] if self.kind == "rnn" else state[-2]

    def _layers(self) -> list[Layer]:
        """(W, B, b) of every layer, gathered once for a whole unfolding (a ParameterList's lookups are slow); B is
        None in a layer without memory."""
        recurrent = list(self.recurrent_weights) or [None] * len(self.hidden)
        return list(zip(self.input_weights, recurrent, self.biases, strict=True))

    def _advance(
        self, x: torch.Tensor, state: list[torch.Tensor], layers: list[Layer]
    ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The stacked ``layers`` on network inputs x (K, B, ·) = (normalised o_t, a_t): read-outs y_t (3.7), new
        state. Each recurrent layer's cell is the recurrent policies' own (``drrl.policies.recurrent``)."""
        cell, memories = CELLS[self.kind], MEMORIES[self.kind]
        new_state = []
        for i, (w, b, bias) in enumerate(layers):
            memory = tuple(state[memories * i : memories * (i + 1)])
            pre_activation = torch.baddbmm(bias, x, w)
            if b is not None:
                pre_activation = torch.baddbmm(pre_activation, memory[0], b)
            x, memory = cell(pre_activation, memory)
            new_state += memory
        return torch.baddbmm(self.readout_bias, x, self.readout_weight), new_state

    def _normalise(self, observation: torch.Tensor) -> torch.Tensor:
        return (observation - per_member(self.observation_mean, observation)) / per_member(
            self.observation_scale, observation
        )

    def _next_observation(self, observation: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        change = y[..., :-2]
        return observation + change * per_member(self.change_scale, change)

    def _heads(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reward and end probability from read-outs y."""
        reward = y[..., -2]
        return (
            reward * per_member(self.reward_scale, reward) + per_member(self.reward_mean, reward),
            torch.sigmoid(y[..., -1]),
        )

    def _per_member_inputs(self, tensor: torch.Tensor, per_member_ndim: int) -> torch.Tensor:
        """``tensor`` with its leading member dimension K, added (every member reads the same) if it lacks one."""
        if tensor.dim() == per_member_ndim:
            return tensor.expand(self.members, *tensor.shape)
        if tensor.dim() != per_member_ndim + 1 or tensor.shape[0] != self.members:
            raise ValueError(
                f"expected a tensor of {per_member_ndim} dimensions, or {per_member_ndim + 1} with "
                f"{self.members} member(s) first, got shape {tuple(tensor.shape)}"
            )
        return tensor

    def step(
        self,
        observation: torch.Tensor,
        action: torch.Tensor,
        state: list[torch.Tensor],
        observed: bool | torch.Tensor = True,
    ) -> tuple[Prediction, list[torch.Tensor]]:
        """One unfolded step for a batch: o_t (B, o) and a_t (B, a), read by every member, or (K, B, ·) each its
        own → every member's prediction of step t+1 (K, B, ·), new state.

        ``observed`` (a bool, or one per sequence, (B,) or (K, B)) False marks a step of the overshooting part: with
        ``future_inputs="zeros"`` the network then reads 0 instead of ``observation`` (which is still the base the
        predicted change is added to).
        """
        observation = self._per_member_inputs(observation, 2)
        x = self._normalise(observation)
        if self.future_inputs == "zeros" and observed is not True:
            x = x * torch.as_tensor(observed, dtype=x.dtype, device=x.device).unsqueeze(-1)
        y, new_state = self._advance(torch.cat([x, self._per_member_inputs(action, 2)], dim=-1), state, self._layers())
        rewards, ends = self._heads(y)
        return Prediction(self._next_observation(observation, y), rewards, ends), new_state

    def unfold(
        self,
        observations: torch.Tensor,
        actions: torch.Tensor,
        observed_steps: int,
        previous_actions: torch.Tensor | None = None,
    ) -> Prediction:
        """Unfold over windows of L steps: observations o_0..o_{L−1} (B, L, o), actions a_0..a_{L−1} (B, L, a),
        the same for every member, or (K, B, L, ·) each member its own. ``previous_actions``, what came before the
        windows, is not read: every window starts from the zero state.

        Steps t < ``observed_steps`` read o_t from the data; the later ones are the overshooting part and read the
        model's own prediction ô_t (dynamical consistency), never the data. Returns each member's predictions of
        o_1..o_L, r_1..r_L and the ends, (K, B, L, …).

        The same computation as L calls of ``step``, with the per-step work cut to what the recurrence needs, since
        fitting spends most of its time here: the fed-back observation is carried in normalised units,
        (ô_{t+1} − mean) / std(o) = (ô_t − mean) / std(o) + y_t[obs] · std(Δo) / std(o), so that no step normalises
        again, and the layers' weights are looked up once.
        """
        observations, actions = self._per_member_inputs(observations, 3), self._per_member_inputs(actions, 3)
        batch, length = actions.shape[1:3]
        if not 1 <= observed_steps <= length:
            raise ValueError(
                f"observed_steps must be in [1, {length}] for windows of {length} steps, got {observed_steps}"
            )
        mean, scale = per_member(self.observation_mean, observations), per_member(self.observation_scale, observations)
        observed = ((observations[:, :, :observed_steps] - mean) / scale).unbind(2)
        change = per_member(self.change_scale / self.observation_scale, observed[0])
        size, layers = self.observation_size, self._layers()
        state, outputs, predicted = self.initial_state(batch), [], []
        for t, action in enumerate(actions.unbind(2)):
            if t < observed_steps:
                fed = observed[t]
            read = fed if t < observed_steps or self.future_inputs == "predictions" else torch.zeros_like(fed)
            y, state = self._advance(torch.cat([read, action], dim=-1), state, layers)
            fed = torch.addcmul(fed, y[..., :size], change)
            outputs.append(y)
            predicted.append(fed)
        rewards, ends = self._heads(torch.stack(outputs, dim=2))
        return Prediction(observations=torch.stack(predicted, dim=2) * scale + mean, rewards=rewards, ends=ends)

    def disagreement(self, prediction: Prediction) -> torch.Tensor:
        """(B,) the members' spread: the standard deviation over members of the predicted observation, in units of
        the data's per-step change, averaged over the observation's entries; 0 for a single member."""
        return spread(prediction, self.change_scale)

    def describe(self) -> str:
        layers = "×".join(map(str, self.hidden))
        return f"{self.kind} {layers}, future inputs: {self.future_inputs}, {self.members} member(s)"


def window_losses(
    model: WorldModel,
    prediction: Prediction,
    next_observations: torch.Tensor,
    rewards: torch.Tensor,
    ends: torch.Tensor,
    mask: torch.Tensor,
    learn_reward: bool = True,
) -> torch.Tensor:
    """(K, B) each member's squared error summed over the unfolded steps of each window (3.12–3.13, squared).

    Observation errors are measured in units of the data's per-step change (so a k-step error is comparable to k
    one-step errors), rewards in units of their standard deviation; ``mask`` (B, L) or (K, B, L) drops steps past
    an episode's end. With ``learn_reward=False`` (the task's reward is known in closed form) the reward and end
    heads are not trained. The targets are (B, L, ·), the same for every member, or (K, B, L, ·).
    """
    error = (
        ((prediction.observations - next_observations) / per_member(model.change_scale, prediction.observations))
        .square()
        .sum(-1)
    )
    if learn_reward:
        error = error + ((prediction.rewards - rewards) / per_member(model.reward_scale, prediction.rewards)).square()
        error = error + (prediction.ends - ends).square()
    return (error * mask).sum(-1)


def unfolding_loss(
    model: WorldModel,
    prediction: Prediction,
    next_observations: torch.Tensor,
    rewards: torch.Tensor,
    ends: torch.Tensor,
    mask: torch.Tensor,
    learn_reward: bool = True,
) -> torch.Tensor:
    """(K,) each member's ``window_losses`` averaged over the windows."""
    return window_losses(model, prediction, next_observations, rewards, ends, mask, learn_reward).mean(-1)


def _uniform(members: int, rows: int, columns: int, width: int) -> nn.Parameter:
    bound = 1.0 / math.sqrt(width)
    return nn.Parameter(torch.empty(members, rows, columns).uniform_(-bound, bound))
