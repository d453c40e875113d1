"""Recurrent policies: the partially observed cart-pole, the full cart-pole, and the speed of a batched LSTM.

1. Partially observed cart-pole (drrl/CartPolePO-v0, only (s, θ) seen; thesis 2.1.1): real training episodes until
   the centre policy is balanced (50 of 50 evaluation episodes, the training loop's per-generation `balanced`
   column) and near-optimal, median over seeds, for recurrent policies and for feed-forward policies of similar
   parameter count, all in the same run under the same budget. Feed-forward policies run with drrl's defaults and
   with the recurrent policies' settings (PO_SETTINGS); the table shows both.
2. Full cart-pole (drrl/CartPole-v0): the default (linear) policy with drrl's defaults against recurrent policies
   with FULL_SETTINGS.
3. Throughput: P = 100 candidates, one episode each, on the batched cart-pole: LSTM(16) and, for scale, linear.

Run on one core:

    taskset -c 0 python benchmarks/partially_observed.py --seeds 10
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from sample_efficiency import first_reached, median_or_miss

from drrl.envs.batch import make_batch_env
from drrl.policies import Policy, make_policy
from drrl.rollout import evaluate
from drrl.settings import TrainConfig
from drrl.settings.flat import flattened
from drrl.training.train import train

# PGPE settings for recurrent policies, tuned on 4 seeds per task (see BENCHMARKS.md). Both use a σ below the
# default 1.0: every recurrent weight is perturbed, and a w × w recurrent block with N(0, 1) entries has spectral
# radius ≈ √w, deep in saturation. The partially observed task prefers centred ranks, a smaller step and more
# candidates per generation; the full task prefers raw returns (a fall costs hundreds) and larger steps.
PO_SETTINGS = dict(
    popsize=16,
    sampler="symmetric",
    optimizer="clipup",
    center_lr=0.1,
    sigma_init=0.2,
    sigma_lr=0.05,
    fitness_shaping="centered_ranks",
)
FULL_SETTINGS = dict(
    popsize=8,
    sampler="symmetric",
    optimizer="clipup",
    center_lr=0.2,
    sigma_init=0.3,
    sigma_lr=0.01,
    fitness_shaping="none",
)
DEFAULTS: dict = {}  # TrainConfig's defaults

CRITERIA = ("balanced", "near_optimal")


def episodes_to_criteria(env: str, policy: str, settings: dict, seeds: int, budget: int) -> dict[str, list]:
    """Per criterion, the real training episodes each seed needed to first meet it (None if never)."""
    reached: dict[str, list] = {criterion: [] for criterion in CRITERIA}
    for seed in range(seeds):
        rows = train(
            TrainConfig(env=env, policy=policy, seed=seed, budget=budget, eval_share=1.0, **settings), progress=False
        ).rows
        for criterion in CRITERIA:
            reached[criterion].append(first_reached(rows, criterion))
    return reached


def sample_efficiency_table(env: str, runs: list[tuple[str, str, dict]], seeds: int, budget: int) -> None:
    print(f"\n{env}, budget {budget} real episodes, {seeds} seeds\n")
    print(
        "| policy | parameters | settings | median episodes to balanced | seeds balanced "
        "| median to near-optimal | seeds near-optimal |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    observation_size = make_batch_env(env, 1).single_observation_space.shape[0]
    for policy, label, settings in runs:
        reached = episodes_to_criteria(env, policy, settings, seeds, budget)
        hits = {c: sum(v is not None for v in reached[c]) for c in CRITERIA}
        parameters = make_policy(policy, observation_size, 1).num_params
        print(
            f"| {policy} | {parameters} | {label} | {median_or_miss(reached['balanced'])} "
            f"| {hits['balanced']}/{seeds} | {median_or_miss(reached['near_optimal'])} "
            f"| {hits['near_optimal']}/{seeds} |",
            flush=True,
        )


def balancing_lstm(policy: Policy) -> torch.Tensor:
    """LSTM weights that balance the full cart-pole: unit 0's gates are held open (input, output) and shut (forget),
    its cell input is a small multiple of a linear balancing feedback, and the read-out scales it back, so that
    a ≈ k·(s, ṡ, θ, θ̇). Episodes then run their full 200 steps, as in late training."""
    gain = torch.tensor([0.05, 0.1, 1.5, 0.2])  # the balancing linear controller of benchmarks/throughput.py
    small = 0.05  # keeps tanh(tanh(small · k·x)) ≈ small · k·x
    width = policy.hidden[0]
    fused, bias, read_out, _ = [w[0] for w in policy.unflatten(torch.zeros(1, policy.num_params))]
    fused[:4, 3 * width] = small * gain  # the cell-input column (gate order i, f, o, g) of unit 0
    bias[0, [0, width, 2 * width]] = torch.tensor([10.0, -10.0, 10.0])  # input open, forget shut, output open
    read_out[0, 0] = 1 / small
    return torch.cat([fused.flatten(), bias.flatten(), read_out.flatten(), torch.zeros(1)])


def throughput(spec: str, population: int, repeats: int) -> tuple[float, float, int]:
    """Median env-steps per wall-clock second and per CPU second of one batched rollout of ``population``
    near-balancing candidates, and its steps. On a shared machine the CPU-time rate is the steadier of the two."""
    env = make_batch_env("cartpole", population)
    policy = make_policy(spec, 4, 1)
    center = balancing_lstm(policy) if spec.startswith("lstm") else torch.tensor([0.05, 0.1, 1.5, 0.2, 0.0])
    noise = torch.randn(population, policy.num_params, generator=torch.Generator().manual_seed(0))
    candidates = center + 0.001 * noise
    wall, cpu = [], []
    for repeat in range(repeats):
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        result = evaluate(policy, candidates, env, episodes=1, seed=repeat)
        wall.append(result.steps / (time.perf_counter() - wall_start))
        cpu.append(result.steps / (time.process_time() - cpu_start))
    return statistics.median(wall), statistics.median(cpu), result.steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--budget", type=int, default=2000, help="real episodes on the partially observed task")
    parser.add_argument("--full-budget", type=int, default=1000, help="real episodes on the full cart-pole")
    parser.add_argument("--recurrent", default="rnn:4,lstm:4", help="recurrent policies to compare")
    parser.add_argument("--feedforward", default="linear,mlp:8", help="feed-forward policies on the PO task")
    parser.add_argument("--sections", default="po,full,throughput")
    parser.add_argument("--repeats", type=int, default=7, help="rollouts timed per throughput measurement")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sections = args.sections.split(",")
    recurrent = [spec for spec in args.recurrent.split(",") if spec]
    feedforward = [spec for spec in args.feedforward.split(",") if spec]
    defaults = flattened(TrainConfig())
    print(f"defaults: { {name: defaults[name] for name in (*PO_SETTINGS, 'policy') if name in defaults} }")
    print(f"PO settings: {PO_SETTINGS}\nfull settings: {FULL_SETTINGS}")
    if "po" in sections:
        runs = [(spec, "PO", PO_SETTINGS) for spec in recurrent]
        runs += [
            (spec, label, settings)
            for spec in feedforward
            for label, settings in (("defaults", DEFAULTS), ("PO", PO_SETTINGS))
        ]
        sample_efficiency_table("cartpole-po", runs, args.seeds, args.budget)
    if "full" in sections:
        runs = [(TrainConfig().policy, "defaults", DEFAULTS)] + [(spec, "full", FULL_SETTINGS) for spec in recurrent]
        sample_efficiency_table("cartpole", runs, args.seeds, args.full_budget)
    if "throughput" in sections:
        print("\n| policy | env-steps per wall-clock s | env-steps per CPU s | steps per rollout |")
        print("| --- | --- | --- | --- |")
        for spec in ("lstm:16", "linear"):
            wall, cpu, steps = throughput(spec, 100, args.repeats)
            print(f"| {spec}, P = 100 | {wall:,.0f} | {cpu:,.0f} | {steps} |", flush=True)


if __name__ == "__main__":
    main()
