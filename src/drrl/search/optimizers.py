"""Step rules for PGPE's centre μ: torch's own SGD and Adam, and ClipUp; and the thesis's own optimizers.

PGPE estimates an ascent direction g and hands it to a ``torch.optim`` optimizer as the gradient of a loss, −g, so
that every torch optimizer (they all minimise) climbs the fitness. "sgd" without options is plain gradient ascent
μ ← μ + α g, the thesis's update (2.31, Algorithm 2).

The thesis trained its recurrent networks with Nesterov's accelerated gradient (3.24) and Adam with a decaying β1
(Algorithm 4): :class:`NesterovAG` and :class:`AdamLambda`, used to fit the world models (drrl.models.fit).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch

OPTIMIZERS = ("sgd", "adam", "clipup")

# The keyword arguments each optimizer accepts through ``optimizer_options`` (its step size is always center_lr).
OPTIMIZER_OPTIONS = {
    "sgd": ("momentum", "dampening", "nesterov", "weight_decay"),
    "adam": ("betas", "eps", "weight_decay", "amsgrad"),
    "clipup": ("momentum", "max_speed"),
}


class ClipUp(torch.optim.Optimizer):
    """ClipUp (Toklu, Liskowski, Srivastava 2020, "ClipUp: a simple and powerful optimizer for distribution-based
    policy evolution"): momentum on the normalised gradient, with the velocity's norm clipped.

    With g the ascent direction (the negative of ``p.grad``), every step does::

        v ← momentum · v + lr · g / ‖g‖
        v ← v · min(1, max_speed / ‖v‖)
        θ ← θ + v

    so each step is at most ``max_speed`` long whatever the scale of the fitness. Norms are taken over all
    parameters of a group together. The paper's advice, used as defaults: momentum 0.9 and max_speed = 2 · lr
    (fixed when the optimizer is built). A zero gradient adds nothing to the velocity.
    """

    def __init__(self, params: Iterable[torch.Tensor], lr: float, momentum: float = 0.9,
                 max_speed: float | None = None):
        if max_speed is None:
            max_speed = 2.0 * lr
        for name, value in (("lr", lr), ("max_speed", max_speed)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ClipUp {name} must be a positive finite number, got {value}")
        if not 0.0 <= momentum < 1.0:
            raise ValueError(f"ClipUp momentum must be in [0, 1), got {momentum}")
        super().__init__(params, dict(lr=lr, momentum=momentum, max_speed=max_speed))

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            tiny = torch.finfo(params[0].dtype).tiny
            grad_norm = torch.sqrt(sum(p.grad.square().sum() for p in params))
            scale = group["lr"] / grad_norm.clamp_min(tiny)
            velocities = []
            for p in params:
                state = self.state[p]
                if "velocity" not in state:
                    state["velocity"] = torch.zeros_like(p)
                velocity = state["velocity"]
                velocity.mul_(group["momentum"]).sub_(p.grad * scale)
                velocities.append(velocity)
            speed = torch.sqrt(sum(v.square().sum() for v in velocities))
            shrink = (group["max_speed"] / speed.clamp_min(tiny)).clamp(max=1.0)
            for p, velocity in zip(params, velocities):
                velocity.mul_(shrink)
                p.add_(velocity)
        return loss


def make_optimizer(name: str, params: Iterable[torch.Tensor], lr: float,
                   options: dict | None = None) -> torch.optim.Optimizer:
    """One of :data:`OPTIMIZERS` over ``params`` with step size ``lr`` and the extra keyword ``options``."""
    if name not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {name!r}; choose one of: {', '.join(OPTIMIZERS)}")
    options = dict(options or {})
    unknown = sorted(set(options) - set(OPTIMIZER_OPTIONS[name]))
    if unknown:
        raise ValueError(f"optimizer {name!r} does not take option(s) {', '.join(map(repr, unknown))}; "
                         f"it accepts: {', '.join(OPTIMIZER_OPTIONS[name])} (its step size is center_lr)")
    if name == "sgd":
        return torch.optim.SGD(params, lr=lr, **options)
    if name == "adam":
        if "betas" in options:
            options["betas"] = tuple(options["betas"])
        return torch.optim.Adam(params, lr=lr, **options)
    return ClipUp(params, lr=lr, **options)


# ---------------------------------------------------------------------------------------------------- the thesis's


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
            raise RuntimeError("NesterovAG.step needs a closure that zeroes the gradients, recomputes the loss and "
                               "calls backward(): 3.24 takes the gradient at the look-ahead point θ + μΔ")
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

    def __init__(self, params: Iterable[torch.Tensor], lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8, lambda_: float = 1 - 1e-8):
        if not (math.isfinite(lr) and lr > 0):
            raise ValueError(f"AdamLambda lr must be a positive finite number, got {lr}")
        for name, value in (("beta1", betas[0]), ("beta2", betas[1]), ("lambda_", lambda_)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"AdamLambda {name} must be in [0, 1], got {value}")
        if betas[0] == 1.0 or betas[1] == 1.0:
            raise ValueError(f"AdamLambda betas must be below 1 (their bias corrections divide by 1 − β^t), "
                             f"got {betas}")
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
