"""PPO from Stable-Baselines3 as an outside reference for ``drrl compare`` (extra ``drrl[sb3]``).

Stable-Baselines3's PPO (Schulman et al. 2017) with its default settings trains on the same env as drrl's methods
(``gymnasium.make`` of the registered id, one env), and is measured the same way: after each of its updates, its
deterministic policy runs on drrl's measuring episodes (through ``drrl.rollout.evaluate``, on a separate env), and
that return is recorded against the real training episodes finished so far. A run stops as its budget's last
episode ends, and is measured once more. PPO's networks are its own (64 × 64 tanh, a separate value network), not
the drrl policy of the other methods.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces

from drrl.envs.batch import ActionMap, make_batch_env, observation_size
from drrl.envs.registry import lookup
from drrl.policies.base import Policy
from drrl.rollout import evaluate
from drrl.streams import Stream, derive_seed

INSTALL = 'PPO needs Stable-Baselines3: pip install "drrl[sb3]"'


class PPOPolicy(Policy):
    """A Stable-Baselines3 policy's deterministic action as drrl's raw output (the inverse of ``ActionMap``), so
    ``evaluate`` runs and counts it as any drrl policy. It has no weights of its own to search."""

    def __init__(self, model, action_space: spaces.Space):
        self.action_map = ActionMap(action_space)
        super().__init__(observation_size(model.observation_space), self.action_map.size, [(1,)])
        self.model = model

    def act(self, weights: list[torch.Tensor], obs: torch.Tensor, state: Any) -> tuple[torch.Tensor, Any]:
        actions, _ = self.model.predict(obs.reshape(-1, obs.shape[-1]).cpu().numpy(), deterministic=True)
        return torch.as_tensor(self.action_map.raw(actions)).view(*obs.shape[:2], -1), state

    def initial_center(self, generator: torch.Generator | None = None) -> torch.Tensor:
        return torch.zeros(1)


def require_sb3() -> None:
    """Raise ValueError with the pip command if Stable-Baselines3 is missing."""
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        raise ValueError(INSTALL) from None


def run_ppo(env: str, seed: int, budget: int, eval_episodes: int = 50) -> list[dict]:
    """A row per measurement, as ``drrl train``'s metrics: the real training episodes and steps so far, the
    deterministic policy's measured return and the task's verdict on it; after every update, until ``budget`` real
    episodes have finished."""
    require_sb3()
    import gymnasium
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    entry = lookup(env)
    env_id = entry.env_id
    measuring = make_batch_env(env_id, eval_episodes, "auto")
    model = PPO("MlpPolicy", gymnasium.make(env_id), seed=seed, device="cpu")
    policy = PPOPolicy(model, measuring.single_action_space)
    rows: list[dict] = []

    def measure(episodes: int) -> None:
        measured = evaluate(
            policy, torch.zeros(1, 1), measuring, eval_episodes, seed=derive_seed(seed, len(rows) + 1, Stream.MEASURING)
        )
        verdict = entry.judge(measured.episode_returns, measured.terminated)
        rows.append(
            {
                "real_episodes": episodes,
                "real_steps": model.num_timesteps,
                "center_return": float(measured.returns[0]),
                **{name: int(met) for name, met in verdict.items()},
            }
        )

    class Counting(BaseCallback):
        episodes = 0

        def _on_rollout_start(self) -> None:  # after every update
            if self.episodes:
                measure(self.episodes)

        def _on_step(self) -> bool:
            self.episodes += int(np.count_nonzero(self.locals["dones"]))
            return self.episodes < budget

    counting = Counting()
    try:
        model.learn(total_timesteps=2**62, callback=counting)
        measure(counting.episodes)
    finally:
        measuring.close()
    return rows
