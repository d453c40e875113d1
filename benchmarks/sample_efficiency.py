"""Real training episodes until the centre policy is balanced / near-optimal on the thesis cart-pole (5.1).

For each method and seed, `drrl train`'s defaults (bias-free linear policy) spend a budget of real episodes; the
centre policy is measured on 50 fresh episodes after every generation (`eval_share` 1; counted apart, never as
training). Prints a Markdown table of medians over seeds. A method is a PGPE sampler or another search (cmaes,
sep-cmaes), which keeps the same popsize, σ₀ and budget.

    python benchmarks/sample_efficiency.py --seeds 10 --workers 2
    python benchmarks/sample_efficiency.py --seeds 10 --workers 2 --samplers symmetric,cmaes,sep-cmaes
"""

from __future__ import annotations

import argparse
import statistics
from multiprocessing import Pool

import torch

from drrl.search import SEARCHES
from drrl.settings import TrainConfig
from drrl.settings.flat import flattened
from drrl.training.train import train

CRITERIA = ("balanced", "near_optimal")


def first_reached(rows: list[dict], criterion: str) -> int | None:
    """Real training episodes spent when the centre first met ``criterion``; None if never."""
    return next((row["real_episodes"] for row in rows if row.get(criterion) == 1), None)


def median_or_miss(values: list[int | None]) -> str:
    """Median over seeds, a miss counting as worse than any hit."""
    median = statistics.median(float("inf") if v is None else v for v in values)
    return "not reached" if median == float("inf") else f"{median:g}"


def episodes_to_criteria(job: tuple[str, int, int]) -> list[int | None]:
    method, seed, budget = job
    torch.set_num_threads(1)
    choice = {"search": method} if method in SEARCHES else {"sampler": method}
    rows = train(TrainConfig(**choice, seed=seed, budget=budget, eval_share=1.0), progress=False).rows
    return [first_reached(rows, criterion) for criterion in CRITERIA]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--budget", type=int, default=1000)
    parser.add_argument("--samplers", default="symmetric,reinforce,supersymmetric")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    print(f"budget {args.budget} real episodes, seeds 0..{args.seeds - 1}; defaults: {flattened(TrainConfig())}\n")
    print(
        "| method | median episodes to balanced | median episodes to near-optimal | seeds balanced | "
        "seeds near-optimal | per seed (balanced / near-optimal) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    with Pool(args.workers) as pool:
        for sampler in args.samplers.split(","):
            jobs = [(sampler, seed, args.budget) for seed in range(args.seeds)]
            balanced, near_optimal = zip(*pool.map(episodes_to_criteria, jobs), strict=True)
            per_seed = " ".join(f"{b}/{n}" for b, n in zip(balanced, near_optimal, strict=True))
            print(
                f"| {sampler} | {median_or_miss(balanced)} | {median_or_miss(near_optimal)} "
                f"| {sum(b is not None for b in balanced)}/{args.seeds} "
                f"| {sum(n is not None for n in near_optimal)}/{args.seeds} | {per_seed} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
