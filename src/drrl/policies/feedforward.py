"""Feed-forward policies: linear (thesis 2.14), multi-layer linear (5.9) and tanh networks (3.3).

All three are one stack of dense layers ``x ← f(x W + b)``; they differ in the hidden activation and the bias.
The output layer is always linear: bounding the action is the environment adapter's job (see drrl.envs.batch).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from drrl.policies.base import Policy


class FeedForward(Policy):
    """A dense stack evaluated for P candidates × B environments with one batched product per layer."""

    def __init__(
        self,
        observation_size: int,
        action_size: int,
        hidden: Sequence[int] = (),
        *,
        activation: str = "tanh",
        bias: bool = True,
    ):
        if activation not in ("tanh", "identity"):
            raise ValueError(f"activation must be 'tanh' or 'identity', got {activation!r}")
        self.widths = [observation_size, *hidden, action_size]
        self.activation = activation
        self.bias = self.input_bias = bias
        shapes: list[tuple[int, ...]] = []
        for fan_in, fan_out in zip(self.widths[:-1], self.widths[1:], strict=True):
            shapes.append((fan_in, fan_out))
            if bias:
                shapes.append((1, fan_out))
        super().__init__(observation_size, action_size, shapes)

    def act(self, weights, obs, state=None):
        step = 2 if self.bias else 1
        x = obs
        for i in range(0, len(weights), step):
            x = torch.baddbmm(weights[i + 1], x, weights[i]) if self.bias else torch.bmm(x, weights[i])
            if i + step < len(weights) and self.activation == "tanh":
                x = torch.tanh(x)
        return x, state

    def initial_center(self, generator=None):
        """Hidden weights ~ N(0, 1/fan_in) so tanh units start unsaturated; biases and output layer 0.

        A zero output layer makes the initial policy act 0 everywhere, and keeps a plain linear policy at the
        origin, the usual PGPE start. Hidden weights must not all be 0: their gradient would vanish.
        """
        pieces = []
        output_layer = len(self.widths) - 2
        for layer, (fan_in, fan_out) in enumerate(zip(self.widths[:-1], self.widths[1:], strict=True)):
            if layer == output_layer:
                pieces.append(torch.zeros(fan_in * fan_out))
            else:
                pieces.append(torch.randn(fan_in * fan_out, generator=generator) / fan_in**0.5)
            if self.bias:
                pieces.append(torch.zeros(fan_out))
        return torch.cat(pieces)


def linear(observation_size: int, action_size: int, bias: bool = True) -> FeedForward:
    """a = W s (+ b): the thesis's linear PGPE policy (2.14 with n = 1)."""
    return FeedForward(observation_size, action_size, (), activation="identity", bias=bias)


def multilinear(observation_size: int, action_size: int, hidden: Sequence[int]) -> FeedForward:
    """π(s) = (f_1 ∘ … ∘ f_n)(s) with f_i(s) = W_i s: the thesis's multi-layer linear network (5.9), no bias."""
    return FeedForward(observation_size, action_size, hidden, activation="identity", bias=False)


def mlp(observation_size: int, action_size: int, hidden: Sequence[int]) -> FeedForward:
    """Hidden layers f(x) = tanh(W x + b) (3.3), a linear read-out."""
    return FeedForward(observation_size, action_size, hidden, activation="tanh", bias=True)
