"""The episodic natural actor-critic, eNAC (Peters and Schaal 2008; thesis 2.1.4, 2.5–2.7).

The natural gradient (2.6) is G⁻¹∇J, G the Fisher information of the policy. With the compatible critic of 2.7,
R ≈ (∇ log π)ᵀ w, the natural gradient is the critic's own weight vector w, and over whole episodes it is found by
least squares: for every episode e, with ψ_e = Σ_t ∇_θ log π_θ(a_t | o_0..o_t) (summed over its steps) and R_e
its return,

    R_e ≈ ψ_eᵀ w + J

over the batch; J, the intercept, is the average return (the baseline b of 2.7). Centring ψ and R over the
batch gives w without J: w = argmin ‖(Ψ − ψ̄) w − (R − R̄)‖², the minimum-norm solution when the batch holds fewer
episodes than the policy has parameters (a large network; the estimate is then poor, as eNAC's always is there).
θ then steps along w by the configured step rule (2.12 with "sgd"; ClipUp by default, whose normalised step makes the
step size independent of the returns' scale). Each episode's ψ_e comes from one backward pass, every episode
running on its own copy of θ.
"""

from __future__ import annotations

import torch

from drrl.policy_gradient.base import PolicyGradient
from drrl.policy_gradient.episodes import Episodes, log_probs


class ENAC(PolicyGradient):
    kind = "enac"

    def ascent(self, episodes: Episodes) -> tuple[torch.Tensor, torch.Tensor]:
        batch = episodes.alive.shape[1]
        theta = self.theta.detach().expand(batch, -1).clone().requires_grad_(True)
        log_std = self.log_std.detach().expand(batch, -1).clone().requires_grad_(True)
        logp = log_probs(self.policy, theta, log_std, episodes, self.discrete)[:, :, 0]  # (T, B)
        total = (logp * episodes.alive.to(logp.device)).sum()
        psi = torch.cat(torch.autograd.grad(total, [theta, log_std], allow_unused=True, materialize_grads=True), 1)
        returns = episodes.evaluation.episode_returns.reshape(-1).to(psi.device)
        centred = (psi - psi.mean(0)).double()
        w = (torch.linalg.pinv(centred) @ (returns - returns.mean())).to(torch.float32)  # the minimum-norm solution
        return w[: self.num_params], w[self.num_params :]
