"""A sparse polynomial world model: the linear model's one-step regression on the monomials of the observation and
action, fitted by sequentially thresholded least squares (SINDy: Brunton, Proctor and Kutz 2016, PNAS 113:3932).

One step extends the linear model's features (``drrl.models.linear``) by every monomial of degree 2 to ``DEGREE``
of the normalised observation and action, z = (normalised o_t, normalised a_t)::

    x_t     = (z_i z_j, z_i z_j z_k for i ≤ j ≤ k,  normalised o_t, a_t, a_{t−1}, 1)
    ô_{t+1} = o_t + (x_t W)[obs] · std(Δo),   kept within ``BOUND`` standard deviations of the data's o

Why, beyond the thesis's recurrent world models (3.3–3.5). A mechanical system's accelerations are smooth functions
of its angles' sines and cosines, its velocities and the force (the cart-pole's are nearly polynomials of degree 3
in them), so a polynomial of the few observed quantities carries a physical model's structure where a recurrent
network must find it in the data. Fitted on the swing-up's first real episodes it predicts many steps ahead several
times closer than the LSTM ensemble, in under a second where the LSTMs take tens of seconds (BENCHMARKS.md,
"Model-based PGPE on the swing-up").

Fitting. Ridge regression as the linear model's, then SINDy's thresholding: every weight below ``THRESHOLD`` (in the
normalised units of features and targets) is set to zero and the target refitted on the features left, until the
kept features stop changing (at most ``SWEEPS`` times). Few terms generalise from few data; a full polynomial fitted
to a few hundred steps would follow their noise.

Departures from SINDy, and why
    * Ridge instead of plain least squares in every solve (λ = ``RIDGE`` per training step): the early episodes of
      a run hold too few distinct states for the 85 features of the swing-up's model to be determined.
    * Predictions are held within ``BOUND`` standard deviations of the fitted data: a polynomial fed its own
      predictions can run away without limit (cubic terms), where any state that far from the data is unknown to
      the model anyway.
"""

from __future__ import annotations

import itertools

import torch

from drrl.models.base import Prediction, per_member
from drrl.models.linear import LinearModel

DEGREE = 3  # the highest monomial
THRESHOLD = 0.01  # SINDy's: weights below it are dropped
SWEEPS = 10  # most thresholding rounds
RIDGE = 1e-5  # λ of every solve, per training step
BOUND = 10.0  # predictions kept within this many standard deviations of the data's mean


class PolynomialModel(LinearModel):
    """K sparse polynomial world models (module docstring), stepped as one; a ``LinearModel`` with more features."""

    ridge = RIDGE

    def __init__(self, observation_size: int, action_size: int, members: int = 1):
        inputs = observation_size + action_size
        monomials = [
            term
            for degree in range(2, DEGREE + 1)
            for term in itertools.combinations_with_replacement(range(inputs), degree)
        ]
        # factor indices of every monomial, degree-padded with the index of a column of ones: (DEGREE, M)
        self.factors = torch.tensor([[*term, *[inputs] * (DEGREE - len(term))] for term in monomials]).T
        super().__init__(observation_size, action_size, members)

    @property
    def num_features(self) -> int:
        return self.factors.shape[1] + super().num_features

    def features(self, observation: torch.Tensor, action: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """x_t (K, …, f): the monomials of (o_t, a_t), then the linear model's features."""
        z = torch.cat(
            [
                (observation - per_member(self.observation_mean, observation))
                / per_member(self.observation_scale, observation),
                (action - per_member(self.action_mean, action)) / per_member(self.action_scale, action),
                torch.ones_like(observation[..., :1]),
            ],
            dim=-1,
        )
        factors = self.factors.to(z.device)
        product = z[..., factors[0]]
        for index in factors[1:]:
            product = product * z[..., index]
        return torch.cat([product, super().features(observation, action, previous)], dim=-1)

    def solve(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Ridge regression, then sequentially thresholded: each target refitted on its features whose weights reach
        ``THRESHOLD``, the constant always kept, until no target's features change."""
        weight = super().solve(x, y)
        kept = torch.ones_like(weight, dtype=torch.bool)
        for _ in range(SWEEPS):
            now = weight.abs() >= THRESHOLD
            now[-1] = True  # the constant feature
            if torch.equal(now, kept):
                break
            kept = now
            for j in range(y.shape[1]):
                weight[:, j] = 0.0
                weight[kept[:, j], j] = super().solve(x[:, kept[:, j]], y[:, j : j + 1])[:, 0]
        return weight

    def describe(self) -> str:
        return f"sparse polynomial of degree {DEGREE}, previous action as memory, {self.members} member(s)"

    def _prediction(self, observation: torch.Tensor, y: torch.Tensor) -> Prediction:
        prediction = super()._prediction(observation, y)
        mean = per_member(self.observation_mean, observation)
        reach = BOUND * per_member(self.observation_scale, observation)
        bounded = torch.maximum(torch.minimum(prediction.observations, mean + reach), mean - reach)
        return Prediction(bounded, prediction.rewards, prediction.ends)
