"""Stable-Baselines3 PPO with the RL Baselines3 Zoo's tuned hyperparameters on Gymnasium's envs: real steps, real
episodes and training wall time until solved, or what it reached within the zoo's budget and a wall-time cap.

Every ``--measure-every`` real steps the deterministic policy plays 10 episodes of a separate env (training's
observation statistics, frozen; raw rewards); at the solved level, 50 fresh episodes confirm it and training
stops. Measuring is not counted in the wall time. No drrl: SB3 and Gymnasium, with the solved levels of
``gymnasium_defaults.py``, the ones drrl's defaults are measured against.

    python benchmarks/ppo_zoo.py --seeds 0
    python benchmarks/ppo_zoo.py --envs Pendulum-v1 --cap-minutes 1
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import torch
from gymnasium_defaults import TARGETS  # the levels drrl's defaults are measured against
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from torch import nn

# The zoo's numbers, from DLR-RM/rl-baselines3-zoo hyperparams/ppo.yml at commit
# 22e3ff2450fd92033f7f032915e1f64894a09584; the zoo entry used is named where it differs from the env.
# n_envs, n_timesteps and normalize are the zoo's own keys; the rest go to PPO (unset ones keep SB3's defaults).
HYPERPARAMS = {
    "Pendulum-v1": dict(
        n_envs=4, n_timesteps=100_000, normalize=False, n_steps=1024, gae_lambda=0.95, gamma=0.9, n_epochs=10,
        ent_coef=0.0, learning_rate=1e-3, clip_range=0.2, use_sde=True, sde_sample_freq=4,
    ),
    "Acrobot-v1": dict(
        n_envs=16, n_timesteps=1_000_000, normalize=True, n_steps=256, gae_lambda=0.94, gamma=0.99, n_epochs=4,
        ent_coef=0.0,
    ),
    "MountainCarContinuous-v0": dict(
        n_envs=1, n_timesteps=20_000, normalize=True, batch_size=256, n_steps=8, gamma=0.9999,
        learning_rate=7.77e-05, ent_coef=0.00429, clip_range=0.1, n_epochs=10, gae_lambda=0.9, max_grad_norm=5,
        vf_coef=0.19, use_sde=True, policy_kwargs=dict(log_std_init=-3.29, ortho_init=False),
    ),
    "InvertedDoublePendulum-v5": dict(  # zoo entry InvertedDoublePendulum-v2
        n_envs=1, n_timesteps=1_000_000, normalize=True, batch_size=512, n_steps=128, gamma=0.98,
        learning_rate=0.000155454, ent_coef=1.05057e-06, clip_range=0.4, n_epochs=10, gae_lambda=0.8,
        max_grad_norm=0.5, vf_coef=0.695929,
    ),
    "Reacher-v5": dict(  # zoo entry Reacher-v2
        n_envs=1, n_timesteps=1_000_000, normalize=True, batch_size=32, n_steps=512, gamma=0.9,
        learning_rate=0.000104019, ent_coef=7.52585e-08, clip_range=0.3, n_epochs=5, gae_lambda=1.0,
        max_grad_norm=0.9, vf_coef=0.950368,
    ),
    "Hopper-v5": dict(  # zoo entry Hopper-v4
        n_envs=1, n_timesteps=1_000_000, normalize=True, batch_size=32, n_steps=512, gamma=0.999,
        learning_rate=9.80828e-05, ent_coef=0.00229519, clip_range=0.2, n_epochs=5, gae_lambda=0.99,
        max_grad_norm=0.7, vf_coef=0.835671,
        policy_kwargs=dict(
            log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, net_arch=dict(pi=[256, 256], vf=[256, 256])
        ),
    ),
}  # fmt: skip


def make_model(env: str, seed: int) -> tuple[PPO, VecEnv, int]:
    """The zoo's setup for ``env``: PPO, a separate evaluation env, and the zoo's n_timesteps."""
    kwargs = copy.deepcopy(HYPERPARAMS[env])
    n_envs, n_timesteps, normalize = kwargs.pop("n_envs"), kwargs.pop("n_timesteps"), kwargs.pop("normalize")
    train_env = make_vec_env(env, n_envs=n_envs, seed=seed)
    eval_env = make_vec_env(env, n_envs=1, seed=seed + 10_000)
    if normalize:
        gamma = kwargs.get("gamma", 0.99)
        train_env = VecNormalize(train_env, gamma=gamma)
        eval_env = VecNormalize(eval_env, gamma=gamma, training=False, norm_reward=False)
    model = PPO("MlpPolicy", train_env, seed=seed, device="cpu", verbose=0, **kwargs)
    return model, eval_env, n_timesteps


def mean_return(model: PPO, eval_env: VecEnv, episodes: int) -> float:
    """Mean raw return of the deterministic policy over ``episodes`` episodes, with training's frozen statistics."""
    if isinstance(eval_env, VecNormalize):
        eval_env.obs_rms = model.get_env().obs_rms.copy()
    mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=episodes, deterministic=True)
    return float(mean)


class Measure(BaseCallback):
    """Counts finished episodes, measures every ``every`` real steps, stops when solved or past the wall cap."""

    def __init__(self, eval_env: VecEnv, target: float, every: int, cap_seconds: float) -> None:
        super().__init__()
        self.eval_env, self.target, self.every, self.cap = eval_env, target, every, cap_seconds
        self.episodes, self.measuring, self.next_at, self.solved_return = 0, 0.0, every, None

    def _on_training_start(self) -> None:
        self.start = time.perf_counter()

    def wall(self) -> float:
        return time.perf_counter() - self.start - self.measuring

    def _on_step(self) -> bool:
        self.episodes += int(self.locals["dones"].sum())
        if self.num_timesteps >= self.next_at:
            self.next_at += self.every
            began = time.perf_counter()
            if mean_return(self.model, self.eval_env, 10) >= self.target:
                confirmed = mean_return(self.model, self.eval_env, 50)
                if confirmed >= self.target:
                    self.solved_return = confirmed
            self.measuring += time.perf_counter() - began
            if self.solved_return is not None:
                return False
        return self.wall() < self.cap


def one_run(env: str, seed: int, every: int, cap_minutes: float) -> dict:
    model, eval_env, n_timesteps = make_model(env, seed)
    measure = Measure(eval_env, TARGETS[env], every, cap_minutes * 60)
    model.learn(total_timesteps=n_timesteps, callback=measure)
    wall = measure.wall()
    solved = measure.solved_return is not None
    final = measure.solved_return if solved else mean_return(model, eval_env, 50)
    return {
        "env": env,
        "seed": seed,
        "solved": solved,
        "steps": model.num_timesteps,
        "episodes": measure.episodes,
        "wall": wall,
        "return": final,
        "n_timesteps": n_timesteps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default=",".join(TARGETS))
    parser.add_argument("--seeds", default="0", help="comma list")
    parser.add_argument("--measure-every", type=int, default=10_000, help="real steps (MountainCarContinuous: 1,000)")
    parser.add_argument("--cap-minutes", type=float, default=20, help="training wall time per run")
    parser.add_argument("--out", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    for env in args.envs.split(","):
        for seed in map(int, args.seeds.split(",")):
            every = min(args.measure_every, 1_000) if env == "MountainCarContinuous-v0" else args.measure_every
            row = one_run(env, seed, every, args.cap_minutes)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                args.out.write_text(json.dumps(rows, indent=1))
    print(
        "| env | seed | solved | real steps | real episodes | wall (training) |",
        "50-episode return | zoo n_timesteps |",
    )
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        print(
            f"| {r['env']} | {r['seed']} | {'yes' if r['solved'] else 'no'} | {r['steps']:,} | {r['episodes']:,} | "
            f"{r['wall']:.0f} s | {r['return']:.1f} | {r['n_timesteps']:,} |"
        )


if __name__ == "__main__":
    main()
