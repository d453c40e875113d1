"""The thesis's optimizers for training recurrent networks (3.5.3), used to fit the world models (drrl.models.fit):
Nesterov's accelerated gradient (3.24) and Adam with a decaying β1 (Algorithm 4)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch


class NesterovAG(torch.optim.Optimizer):
    """Nesterov's accelerated gradient exactly as the thesis writes it (3.24)::

        Δ_t = μ · Δ_{t-1} − α · ∇f(θ_{t-1} + μ · Δ_{t-1})
        θ_t = θ_{t-1} + Δ_t

    The parameters always hold θ itself. The gradient belongs to the look-ahead point θ + μΔ, so ``step`` needs a
    closure that recomputes the loss and its gradient (as ``torch.optim.LBFGS`` does): it moves the parameters to
    the look-ahead point, calls the closure there, and moves them back before stepping.

    How ``torch.optim.SGD(nesterov=True)`` differs: it uses the reformulated form (Sutskever et al. 2013), in which
    the parameters hold the look-ahead point φ = θ + μΔ itself, the gradient is taken at the parameters, and the
    velocity b is kept in gradient units (b ← μ b + g, φ ← φ − α (g + μ b)). With a constant α and no dampening
    the two produce the same sequence of look-ahead points, but torch's parameters end at φ = θ + μΔ, not at θ,
    and a change of α rescales all of torch's past steps. No closure is needed there.
    """

    def __init__(self, params: Iterable[torch.Tensor], lr: float, momentum: float = 0.9):
        if not (math.isfinite(lr) and lr > 0):
            raise ValueError(f"NesterovAG lr must be a positive finite number, got {lr}")
        if not 0.0 <= momentum < 1.0:
            raise ValueError(f"NesterovAG momentum must be in [0, 1), got {momentum}")
        super().__init__(params, dict(lr=lr, momentum=momentum))

    def _shift(self, sign: float) -> None:
        """θ ← θ + sign · μ · Δ for every parameter."""
        for group in self.param_groups:
            for p in group["params"]:
                if "delta" in self.state[p]:
                    p.add_(self.state[p]["delta"], alpha=sign * group["momentum"])

    @torch.no_grad()
    def step(self, closure=None):
        if closure is None:
            raise RuntimeError(
                "NesterovAG.step needs a closure that zeroes the gradients, recomputes the loss and "
                "calls backward(): 3.24 takes the gradient at the look-ahead point θ + μΔ"
            )
        self._shift(+1.0)
        with torch.enable_grad():
            loss = closure()
        self._shift(-1.0)
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if "delta" not in state:
                    state["delta"] = torch.zeros_like(p)
                delta = state["delta"]
                delta.mul_(group["momentum"]).add_(p.grad, alpha=-group["lr"])
                p.add_(delta)
        return loss


class AdamLambda(torch.optim.Optimizer):
    """Adam with the decaying first-moment coefficient of the thesis's Algorithm 4 (Kingma and Ba's first version)::

        β1,t = β1 · λ^(t−1)
        m_t  = β1,t · m_{t−1} + (1 − β1,t) · g_t
        v_t  = β2 · v_{t−1} + (1 − β2) · g_t²
        m̂_t  = m_t / (1 − β1^t),   v̂_t = v_t / (1 − β2^t)
        θ_t  = θ_{t−1} − α · m̂_t / (√v̂_t + ε)

    The bias correction uses β1^t, not the product of the decayed β1,i, as Algorithm 4 prints it. With λ = 1 this
    is ``torch.optim.Adam``. Defaults are the thesis's: α = 0.001, β1 = 0.9, β2 = 0.999, ε = 1e−8, λ = 1 − 1e−8.
    """

    def __init__(
        self,
        params: Iterable[torch.Tensor],
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
        lambda_: float = 1 - 1e-8,
    ):
        if not (math.isfinite(lr) and lr > 0):
            raise ValueError(f"AdamLambda lr must be a positive finite number, got {lr}")
        for name, value in (("beta1", betas[0]), ("beta2", betas[1]), ("lambda_", lambda_)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"AdamLambda {name} must be in [0, 1], got {value}")
        if betas[0] == 1.0 or betas[1] == 1.0:
            raise ValueError(
                f"AdamLambda betas must be below 1 (their bias corrections divide by 1 − β^t), got {betas}"
            )
        super().__init__(params, dict(lr=lr, betas=tuple(betas), eps=eps, lambda_=lambda_))

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state.update(step=0, exp_avg=torch.zeros_like(p), exp_avg_sq=torch.zeros_like(p))
                state["step"] += 1
                t = state["step"]
                beta1_t = beta1 * group["lambda_"] ** (t - 1)
                state["exp_avg"].mul_(beta1_t).add_(p.grad, alpha=1 - beta1_t)
                state["exp_avg_sq"].mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                m_hat = state["exp_avg"] / (1 - beta1**t)
                v_hat = state["exp_avg_sq"] / (1 - beta2**t)
                p.addcdiv_(m_hat, v_hat.sqrt_().add_(group["eps"]), value=-group["lr"])
        return loss
