"""What "solved" means, per task (../shared/reference/cartpole.md for the thesis's cart-pole; drrl.envs.cartpole for
the partially observed and swing-up variants)."""

from __future__ import annotations

import torch

from drrl.envs.baxter.task import reach_verdict
from drrl.envs.cartpole import SWING_UP_SOLVED_RETURN

NEAR_OPTIMAL_RETURN = -50.0


def cartpole_verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
    """balanced: no evaluation episode left the bounds in its 200 steps; near-optimal: balanced and mean ≥ −50."""
    balanced = not bool(terminated.any())
    return {"balanced": balanced,
            "near_optimal": balanced and float(episode_returns.mean()) >= NEAR_OPTIMAL_RETURN}


def swing_up_verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
    """solved: in every evaluation episode the cart stayed on the track and the return reached the threshold."""
    return {"solved": not bool(terminated.any()) and bool((episode_returns >= SWING_UP_SOLVED_RETURN).all())}


VERDICTS = {"drrl/CartPole-v0": cartpole_verdict,
            "drrl/CartPolePO-v0": cartpole_verdict,  # the same task, seen through (s, θ) only
            "drrl/CartPoleSwingUp-v0": swing_up_verdict,
            **{env_id: reach_verdict for env_id in ("drrl/BaxterReach-v0", "drrl/BaxterReachRight-v0",
                                                   "drrl/BaxterReachRightRandom-v0")}}  # reward 5.10 only


def verdict_names(env_id: str) -> tuple[str, ...]:
    """The criteria ``env_id``'s verdict reports (metrics.csv columns); none for an env without a verdict."""
    verdict = VERDICTS.get(env_id)
    return () if verdict is None else tuple(verdict(torch.zeros(1, 1), torch.zeros(1, 1, dtype=torch.bool)))
