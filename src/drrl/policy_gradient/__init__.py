"""Action-space policy gradients, the methods the thesis sets PGPE against (2.1.4, 2.2.2): REINFORCE with a
baseline and the episodic natural actor-critic, behind one interface (``PolicyGradient``)."""

import torch

from drrl.policies.base import Policy
from drrl.policy_gradient.base import PolicyGradient
from drrl.policy_gradient.enac import ENAC
from drrl.policy_gradient.episodes import Episodes, Exploring, collect, log_probs
from drrl.policy_gradient.reinforce import Reinforce

POLICY_GRADIENTS = {"reinforce": Reinforce, "enac": ENAC}


def make_policy_gradient(name: str, policy: Policy, center: torch.Tensor, **settings) -> PolicyGradient:
    """The method ``name`` (one of ``POLICY_GRADIENTS``) from ``center``; ``settings``: discrete, sigma_init, lr,
    optimizer, seed."""
    if name not in POLICY_GRADIENTS:
        raise ValueError(f"unknown policy gradient {name!r}; choose one of: {', '.join(POLICY_GRADIENTS)}")
    return POLICY_GRADIENTS[name](policy, center, **settings)


__all__ = [
    "ENAC",
    "POLICY_GRADIENTS",
    "Episodes",
    "Exploring",
    "PolicyGradient",
    "Reinforce",
    "collect",
    "log_probs",
    "make_policy_gradient",
]
