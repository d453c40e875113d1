"""What drrl knows of some of Gymnasium's own tasks beyond their specs: the return usually counted as solved where
Gymnasium gives none, and rewards and ends in closed form of the next observation and the reward's share that
depends on the action, which a model-based run's imagined episodes use instead of learning them (as model-based
libraries give a task's termination function: a learned end head sees a fall only once an episode), and the
observation entries that follow in closed form from the others, which imagined observations are completed by. The
settings that suit these tasks are presets (``drrl.settings.presets``)."""

from __future__ import annotations

import math

import numpy as np
import torch

# drrl's own levels, each with its source, where a spec gives no reward_threshold or one no policy reaches
# (Pusher-v5's 0: every step costs the distances left); ``drrl eval`` marks them as drrl's.
DRRL_LEVELS: dict[str, tuple[float, str]] = {
    "Pendulum-v1": (-200.0, "the level Pendulum-v1 is usually counted as swung up and held at"),
    "Walker2d-v5": (
        3000.0,
        "below the PPO of Stable-Baselines3's RL Zoo, 3,572 ± 808 on Walker2d-v3 (huggingface.co/sb3/ppo-Walker2d-v3)",
    ),
    "Pusher-v5": (
        -30.0,
        "an arm that keeps still scores -54.4, a Stable-Baselines3 PPO agent -24.9 ± 4.6 "
        "(huggingface.co/Brunocho/ppo-Pusher-v5)",
    ),
}
# What Gymnasium's walkers are paid a step for staying up, at their defaults (their docs' healthy_reward)
ALIVE_BONUS = {"Hopper-v5": 1.0, "Walker2d-v5": 1.0, "Ant-v5": 1.0, "Humanoid-v5": 5.0}


def alive_bonus_note(env_id: str, episode_returns: torch.Tensor, episode_steps: torch.Tensor) -> str | None:
    """A line that calls out a walker farming its alive bonus: its mean return within a quarter above what staying
    up alone pays over its episodes' steps; None for a policy that moves on, or an env without the bonus."""
    bonus = ALIVE_BONUS.get(env_id)
    if bonus is None:
        return None
    alive, mean = bonus * float(episode_steps.double().mean()), float(episode_returns.mean())
    if mean > 1.25 * alive:
        return None
    return (
        f"{alive:.0f} of the mean return {mean:.1f} is the alive bonus ({bonus:g} a step while up): the policy stays "
        "up and hardly moves on"
    )


def cartpole_reward(next_observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's CartPole (classic_control/cartpole.py): a reward of 1 every step, the falling one included; the
    episode ends once the cart (observation 0) leaves ±2.4 m or the pole (observation 2) tilts beyond ±12°."""
    x, theta = next_observations[:, 0], next_observations[:, 2]
    fallen = (np.abs(x) > 2.4) | (np.abs(theta) > 12 * 2 * math.pi / 360)
    return np.ones(len(next_observations)), fallen


def inverted_pendulum_reward(next_observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's InvertedPendulum-v5 (mujoco/inverted_pendulum_v5.py): the episode ends once the pole's angle
    (observation 1) exceeds ±0.2 rad or the observation is not finite; 1 for every step that does not end it."""
    fallen = ~np.isfinite(next_observations).all(axis=1) | (np.abs(next_observations[:, 1]) > 0.2)
    return (~fallen).astype(np.float64), fallen


def pendulum_reward(next_observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's Pendulum-v1 (classic_control/pendulum.py) charges θ² + 0.1 θ̇² + 0.001 u² for the state a step
    starts from and its torque u; here the state it ends in (θ = atan2 of observations 1 and 0, θ̇ observation 2),
    without the torque's share (at most 0.004 a step). Summed over an episode the two differ by the start's cost, the
    same for every policy from that start, the last state's, and the torques'. The episode never ends."""
    cos, sin, velocity = next_observations[:, 0], next_observations[:, 1], next_observations[:, 2]
    return -(np.arctan2(sin, cos) ** 2 + 0.1 * velocity**2), np.zeros(len(next_observations), dtype=bool)


_PENDULUM_FLIP = np.array([1, -1, -1], dtype=np.float32)  # (cos θ, sin θ, θ̇) flipped


def pendulum_mirror(observations: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pendulum-v1 flipped left for right: sin θ, θ̇ and the torque change sign, cos θ does not; its starts (θ and θ̇
    uniform about 0), its cost and its dynamics are symmetric under the flip."""
    return observations * _PENDULUM_FLIP, -actions


def reacher_reward(next_observations: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's Reacher-v5 (mujoco/reacher_v5.py) pays −‖fingertip − target‖ (observations 8 and 9, after the
    step) and −‖a‖² (``reacher_action_cost``) a step. The episode never ends."""
    return -np.linalg.norm(next_observations[:, 8:10], axis=1), np.zeros(len(next_observations), dtype=bool)


def reacher_action_cost(actions: np.ndarray) -> np.ndarray:
    """Reacher-v5's control cost ‖a‖², of the torques the arm receives."""
    return np.square(actions).sum(axis=1)


REACHER_LINKS = (0.1, 0.11)  # m: shoulder to elbow, elbow to fingertip (reacher.xml's body1 and fingertip positions)


def complete_reacher_observation(observations: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Reacher-v5's observation (cos q, sin q, target, q̇, fingertip − target) with what follows from the joint angles
    recomputed: each (cos, sin) pair put back on the unit circle, the target kept where it was (it does not move), and
    the fingertip's offset from it by the arm's forward kinematics. Gymnasium's offset is MuJoCo's kinematics at the
    start of the step's last physics substep, the angles at its end: the two differ by up to about 3 mm."""
    completed = predicted.copy()
    angles = np.arctan2(predicted[:, 2:4], predicted[:, 0:2])
    completed[:, 0:2], completed[:, 2:4] = np.cos(angles), np.sin(angles)
    completed[:, 4:6] = observations[:, 4:6]
    shoulder, elbow = angles[:, 0], angles.sum(axis=1)
    upper, lower = REACHER_LINKS
    completed[:, 8] = upper * np.cos(shoulder) + lower * np.cos(elbow) - completed[:, 4]
    completed[:, 9] = upper * np.sin(shoulder) + lower * np.sin(elbow) - completed[:, 5]
    return completed


REWARDS = {
    "CartPole-v0": cartpole_reward,
    "CartPole-v1": cartpole_reward,
    "InvertedPendulum-v5": inverted_pendulum_reward,
    "Pendulum-v1": pendulum_reward,
    "Reacher-v5": reacher_reward,
}
ACTION_COSTS = {"Reacher-v5": reacher_action_cost}
COMPLETIONS = {"Reacher-v5": complete_reacher_observation}
MIRRORS = {"Pendulum-v1": pendulum_mirror}  # the tasks' reflection symmetries (EnvEntry.mirror)
