"""What "solved" means, per task (../shared/reference/cartpole.md for the thesis's cart-pole)."""

from __future__ import annotations

import torch

NEAR_OPTIMAL_RETURN = -50.0


def cartpole_verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
    """balanced: no evaluation episode left the bounds in its 200 steps; near-optimal: balanced and mean ≥ −50."""
    balanced = not bool(terminated.any())
    return {"balanced": balanced,
            "near_optimal": balanced and float(episode_returns.mean()) >= NEAR_OPTIMAL_RETURN}


VERDICTS = {"drrl/CartPole-v0": cartpole_verdict}
