"""REINFORCE with a baseline (Williams 1992; thesis 2.2.2 and 2.7): the likelihood-ratio gradient in action space.

From B episodes of the stochastic policy π_θ,

    ∇J ≈ 1/B · Σ_b Σ_t ∇ log π_θ(a_t | o_0..o_t) · (G_t − b_t)

where G_t is the return that follows action a_t (every reward after it, undiscounted as the thesis's episodic J
2.11 with a_k = 1) and b_t the baseline of 2.7. Subtracting b_t leaves the estimate unbiased when b_t does not
depend on the episode's own actions, and reduces its variance: here b_t is the mean of G_t over the
*other* B − 1 episodes (leave-one-out), a time-indexed baseline that needs no value function and stays unbiased
for recurrent policies whose "state" is their whole history. Rewards past an episode's end are 0, so a failed
episode's G_t compares with what the others still earned at the same step.
"""

from __future__ import annotations

import torch

from drrl.policy_gradient.base import PolicyGradient
from drrl.policy_gradient.episodes import Episodes, log_probs


class Reinforce(PolicyGradient):
    kind = "reinforce"

    def ascent(self, episodes: Episodes) -> tuple[torch.Tensor, torch.Tensor]:
        batch = episodes.alive.shape[1]
        returns = episodes.rewards_to_go().to(self.theta.device)
        baseline = (returns.sum(1, keepdim=True) - returns) / (batch - 1)
        advantage = ((returns - baseline) * episodes.alive.to(returns.device)).to(torch.float32)
        logp = log_probs(self.policy, self.theta[None], self.log_std[None], episodes, self.discrete)[:, 0]
        objective = (logp * advantage).sum() / batch
        grad_theta, grad_log_std = torch.autograd.grad(
            objective, [self.theta, self.log_std], allow_unused=True, materialize_grads=True
        )
        return grad_theta, grad_log_std
