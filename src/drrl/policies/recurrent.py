"""Recurrent policies: the Elman network (thesis 3.4) and the LSTM (3.15–3.21), stacked to any depth.

A recurrent policy carries a memory from step to step, so it can act on what it no longer observes: the hidden
velocities of the partially observed cart-pole (a POMDP, thesis 2.1.1), a cue shown steps ago. Layer ℓ maps its
input x_t (the observation, or the output of the layer below) and its own previous output h_{t−1} to h_t:

    Elman (3.4)   h_t = tanh(W x_t + B h_{t−1} + b)
    LSTM          z_t = W x_t + U h_{t−1} + b,   (i, f, o) = sigmoid(z_t[:3w]),   g = tanh(z_t[3w:])
                  c_t = f ⊙ c_{t−1} + i ⊙ g,     h_t = o ⊙ tanh(c_t)

and the action is a linear read-out of the top layer, a_t = A h_t + c (as 3.7 reads the model's output off s_t).

Batched and fused. Each layer keeps [W; B] (or [W; U]) as one matrix of shape (in + w, G·w), G = 1 (Elman) or
4 (LSTM gates, in the order i, f, o, g so that one sigmoid covers the three gates). A step of a layer is one
``torch.baddbmm`` of [x_t, h_{t−1}] (P, B, in + w) with it: every candidate p has its own weights, and all P × B
environments advance together.

Memory is a value, never kept by the policy: ``initial_state`` gives fresh zeros for P × B new episodes, ``act``
takes the memory and returns the next one. The evaluator starts every episode from ``initial_state``, so nothing
carries over between candidates, episodes or rollouts (tests/test_recurrent.py checks all three).

Departures from the thesis, and why
    * 3.4 has no bias; we add one (b), as nn.RNNCell does (its two biases add up to our one), so that a unit's
      operating point can move away from 0.
    * 3.15–3.21 are the original LSTM of Hochreiter & Schmidhuber (1997): input and output gates around a cell with a
      fixed self-connection, s_c(t) = s_c(t−1) + g·y^in (3.21), and no forget gate. We add the forget gate of Gers,
      Schmidhuber & Cummins (2000) that modern LSTMs (nn.LSTMCell) have, c_t = f ⊙ c_{t−1} + i ⊙ g: without it the
      cell can only accumulate, and over a 200-step episode it drifts into saturation.
    * 3.21 takes the new input at t − 1 (g(t−1)·y^in(t−1)) while defining g(t−1) = g(net_c(t)); we use step t
      throughout, as 3.15–3.19 do. 3.17–3.19 feed each gate the previous outputs y^u(t−1) of all units u, without a
      bias; we feed the layer's current input x_t and its own previous output h_{t−1}, plus a bias.
    * 3.20 squashes the cell state with "a sigmoid function" h; we use tanh, the zero-centred sigmoid of modern
      LSTMs. There are no peephole connections.
    * The read-out is linear and unbounded, like the feed-forward policies': bounding the action is the env
      adapter's job (clip to [-1, 1] and scale; argmax for a Discrete action). A clipped linear read-out has the
      range of a tanh read-out without its flat tails, and keeps one convention for every policy.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import ClassVar

import torch

from drrl.policies.base import Policy

State = tuple[tuple[torch.Tensor, ...], ...]  # per layer: (h,) for Elman, (h, c) for LSTM; each (P, B, w)

SPECTRAL_RADIUS = 0.5  # of the recurrent block at the initial centre: a fading memory, not a saturated one
FORGET_BIAS = 1.0  # the forget gate starts mostly open (sigmoid(1) ≈ 0.73): memory persists from the start


def elman_cell(
    pre_activation: torch.Tensor, memory: tuple[torch.Tensor, ...]
) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
    """An Elman layer (3.4) from its pre-activation z_t = W x_t + B h_{t−1} + b: (h_t, (h_t,)). The state-space
    world models (drrl.models.recurrent) step their layers with it too."""
    hidden = torch.tanh(pre_activation)
    return hidden, (hidden,)


class Recurrent(Policy):
    """A stack of recurrent layers of the given widths and a linear read-out, for P candidates × B environments.

    Parameters, per layer of width w on an input of size n: the fused matrix (n + w, G·w) (input rows first, then
    the recurrent rows) and its bias (1, G·w); then the read-out (w_top, a) and its bias (1, a).
    """

    gates: ClassVar[int]  # pre-activations per unit: 1 (Elman) or 4 (LSTM)
    memories: ClassVar[int]  # state tensors per layer: 1 (h) or 2 (h, c)

    def __init__(self, observation_size: int, action_size: int, hidden: Sequence[int]):
        self.hidden = [int(width) for width in hidden]
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"a recurrent policy needs one or more positive layer widths, got {list(hidden)}")
        self.inputs = [observation_size, *self.hidden[:-1]]
        shapes: list[tuple[int, ...]] = []
        for fan_in, width in zip(self.inputs, self.hidden, strict=True):
            shapes += [(fan_in + width, self.gates * width), (1, self.gates * width)]
        shapes += [(self.hidden[-1], action_size), (1, action_size)]
        super().__init__(observation_size, action_size, shapes)

    def initial_state(self, population: int, batch: int, device: torch.device | str = "cpu") -> State:
        """Zero memory for P × B fresh episodes: a new tensor per layer and memory, shared with nothing."""
        return tuple(
            tuple(torch.zeros(population, batch, width, device=device) for _ in range(self.memories))
            for width in self.hidden
        )

    def act(self, weights: list[torch.Tensor], obs: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """One step of every layer, bottom to top, then the read-out; returns (raw action (P, B, a), new state)."""
        x = obs
        new_state = []
        for layer, memory in enumerate(state):
            fused, bias = weights[2 * layer], weights[2 * layer + 1]
            pre_activation = torch.baddbmm(bias, torch.cat((x, memory[0]), dim=-1), fused)
            x, memory = self.cell(pre_activation, memory)
            new_state.append(memory)
        return torch.baddbmm(weights[-1], x, weights[-2]), tuple(new_state)

    @abstractmethod
    def cell(self, pre_activation: torch.Tensor, memory: tuple[torch.Tensor, ...]):
        """(output h_t, new memory) of one layer from its fused pre-activation z_t and its memory."""

    def initial_center(self, generator: torch.Generator | None = None) -> torch.Tensor:
        """A starting μ that responds to its inputs, remembers a little and acts 0:

        * input rows ~ N(0, 1/n), n the layer's input size: pre-activations of order 1 for inputs of order 1, so
          tanh and the gates start in their sensitive range, neither linear nor saturated;
        * recurrent rows: one random w × w block per gate, each scaled to spectral radius 0.5: a memory that
          fades rather than one that explodes or saturates, whatever the width;
        * biases 0, except the LSTM forget gate's, +1 (Gers et al. 2000; Jozefowicz et al. 2015): the cell keeps
          its content unless told otherwise;
        * read-out 0: the centre acts 0 everywhere, like the feed-forward policies' start, and PGPE's first
          candidates differ only by their read-out noise and the hidden weights' noise.

        PGPE then adds N(0, σ²) to every parameter. With σ of order 1 the recurrent blocks of the candidates would
        have spectral radius about σ·√w (4 for w = 16, σ = 1), deep in saturation; σ_init ≈ 0.2–0.3 explores
        around this centre without destroying it (benchmarks/partially_observed.py uses 0.2 and 0.3).
        """
        pieces = []
        for fan_in, width in zip(self.inputs, self.hidden, strict=True):
            inputs = torch.randn(fan_in, self.gates * width, generator=generator) / fan_in**0.5
            recurrent = torch.cat(
                [_with_spectral_radius(torch.randn(width, width, generator=generator)) for _ in range(self.gates)],
                dim=1,
            )
            pieces += [inputs.flatten(), recurrent.flatten(), self.initial_bias(width)]
        pieces += [torch.zeros(self.hidden[-1] * self.action_size), torch.zeros(self.action_size)]
        return torch.cat(pieces)

    def initial_bias(self, width: int) -> torch.Tensor:
        return torch.zeros(self.gates * width)


class ElmanRNN(Recurrent):
    """Elman layers h_t = tanh(W x_t + B h_{t−1} + b) (thesis 3.4, with a bias)."""

    gates = 1
    memories = 1

    cell = staticmethod(elman_cell)


class LSTM(Recurrent):
    """LSTM layers with input, forget and output gates (thesis 3.15–3.21 plus the forget gate, Gers et al. 2000).

    The fused pre-activation's columns are ordered (i, f, o, g); nn.LSTMCell orders its rows (i, f, g, o).
    """

    gates = 4
    memories = 2

    def cell(self, pre_activation, memory):
        _, cell = memory
        width = cell.shape[-1]
        input_gate, forget_gate, output_gate = torch.sigmoid(pre_activation[..., : 3 * width]).chunk(3, dim=-1)
        candidate = torch.tanh(pre_activation[..., 3 * width :])
        cell = torch.addcmul(forget_gate * cell, input_gate, candidate)
        hidden = output_gate * torch.tanh(cell)
        return hidden, (hidden, cell)

    def initial_bias(self, width):
        bias = torch.zeros(self.gates * width)
        bias[width : 2 * width] = FORGET_BIAS
        return bias


def _with_spectral_radius(matrix: torch.Tensor, radius: float = SPECTRAL_RADIUS) -> torch.Tensor:
    """``matrix`` rescaled so that its largest eigenvalue modulus is ``radius``."""
    largest = torch.linalg.eigvals(matrix).abs().max()
    return matrix * (radius / largest) if largest > 0 else matrix


def rnn(observation_size: int, action_size: int, hidden: Sequence[int]) -> ElmanRNN:
    """Stacked Elman layers of the given widths and a linear read-out."""
    return ElmanRNN(observation_size, action_size, hidden)


def lstm(observation_size: int, action_size: int, hidden: Sequence[int]) -> LSTM:
    """Stacked LSTM layers of the given widths and a linear read-out."""
    return LSTM(observation_size, action_size, hidden)
