"""Throughput of one PGPE generation on the thesis cart-pole: batched rollout vs a plain one-env-at-a-time loop.

P linear candidates × 1 episode × up to 200 steps. Both paths run the same candidates in the same process, several
times, and the medians are compared. Run on one core:

    taskset -c 0 python benchmarks/throughput.py
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium
import numpy as np
import torch

import drrl  # noqa: F401  (registers drrl/CartPole-v0)
from drrl.envs.batch import make_batch_env
from drrl.policies import linear
from drrl.rollout import evaluate


def batched(policy, candidates, env) -> tuple[float, int]:
    start = time.perf_counter()
    result = evaluate(policy, candidates, env, episodes=1, seed=0)
    return time.perf_counter() - start, result.steps


@torch.inference_mode()
def one_at_a_time(policy, candidates, env) -> tuple[float, int]:
    """Each candidate in turn on a single Gymnasium env, one step and one policy call at a time."""
    start = time.perf_counter()
    steps = 0
    for p in range(candidates.shape[0]):
        weights = policy.unflatten(candidates[p : p + 1])
        obs, _ = env.reset(seed=p)
        done = False
        while not done:
            action, _ = policy.act(weights, torch.as_tensor(obs).view(1, 1, -1), None)
            obs, _, terminated, truncated, _ = env.step(action.view(-1).clamp(-1, 1).numpy())
            steps += 1
            done = terminated or truncated
    return time.perf_counter() - start, steps


def bare_physics(env, repeats: int) -> float:
    """Env-steps/s of the batched env alone with a zero action (the physics and the reward, no policy)."""
    env.reset(seed=0)
    action = np.zeros((env.num_envs, 1), dtype=np.float32)
    start = time.perf_counter()
    for _ in range(repeats):
        env.step(action)
    return repeats * env.num_envs / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--population", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy = linear(4, 1)
    # Candidates near a balancing controller, so that episodes last the full 200 steps as in late training.
    balancing = torch.tensor([0.05, 0.1, 1.5, 0.2, 0.0])
    candidates = balancing + 0.02 * torch.randn(
        args.population, policy.num_params, generator=torch.Generator().manual_seed(0)
    )
    env = make_batch_env("cartpole", args.population)
    single = gymnasium.make("drrl/CartPole-v0")
    fast = [batched(policy, candidates, env) for _ in range(args.repeats)]
    slow = [one_at_a_time(policy, candidates, single) for _ in range(max(3, args.repeats // 2))]
    fast_rate = statistics.median(steps / seconds for seconds, steps in fast)
    slow_rate = statistics.median(steps / seconds for seconds, steps in slow)
    print(f"population {args.population}, linear policy, steps per generation {fast[0][1]}")
    bare = statistics.median(bare_physics(env, 400) for _ in range(args.repeats))
    print(f"bare batched env (zero action):  {bare:>12,.0f} env-steps/s (median of {args.repeats})")
    print(f"batched rollout incl. policy:    {fast_rate:>12,.0f} env-steps/s (median of {len(fast)})")
    print(f"one env at a time (Gymnasium):   {slow_rate:>12,.0f} env-steps/s (median of {len(slow)})")
    print(f"speed-up: {fast_rate / slow_rate:.1f}x")


if __name__ == "__main__":
    main()
