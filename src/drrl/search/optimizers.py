"""Step rules for PGPE's centre μ: torch's own SGD and Adam, and ClipUp.

PGPE estimates an ascent direction g and hands it to a ``torch.optim`` optimizer as the gradient of a loss, −g, so
that every torch optimizer (they all minimise) climbs the fitness. "sgd" without options is plain gradient ascent
μ ← μ + α g, the thesis's update (2.31, Algorithm 2).

The thesis's own optimizers for recurrent networks (3.24, Algorithm 4) fit the world models: drrl.models.optimizers.
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

    def __init__(
        self, params: Iterable[torch.Tensor], lr: float, momentum: float = 0.9, max_speed: float | None = None
    ):
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
            for p, velocity in zip(params, velocities, strict=True):
                velocity.mul_(shrink)
                p.add_(velocity)
        return loss


def make_optimizer(
    name: str, params: Iterable[torch.Tensor], lr: float, options: dict | None = None
) -> torch.optim.Optimizer:
    """One of ``OPTIMIZERS`` over ``params`` with step size ``lr`` and the extra keyword ``options``."""
    if name not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {name!r}; choose one of: {', '.join(OPTIMIZERS)}")
    options = dict(options or {})
    unknown = sorted(set(options) - set(OPTIMIZER_OPTIONS[name]))
    if unknown:
        raise ValueError(
            f"optimizer {name!r} does not take option(s) {', '.join(map(repr, unknown))}; "
            f"it accepts: {', '.join(OPTIMIZER_OPTIONS[name])} (its step size is center_lr)"
        )
    if name == "sgd":
        return torch.optim.SGD(params, lr=lr, **options)
    if name == "adam":
        if "betas" in options:
            options["betas"] = tuple(options["betas"])
        return torch.optim.Adam(params, lr=lr, **options)
    return ClipUp(params, lr=lr, **options)
