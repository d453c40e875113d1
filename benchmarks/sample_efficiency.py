"""Real training episodes until the centre policy is balanced / near-optimal on the thesis cart-pole (5.1).

For each sampler and seed, `drrl train` with its defaults (linear policy) runs for a budget of real episodes; the
centre policy is measured on 50 fresh episodes after every generation (counted apart). Prints medians over seeds.

    python benchmarks/sample_efficiency.py --seeds 10
"""

from __future__ import annotations

import argparse
import statistics

from drrl.config import TrainConfig
from drrl.train import train

CRITERIA = ("balanced", "near_optimal")


def first_reached(rows: list[dict], criterion: str) -> int | None:
    """Real training episodes spent when the centre first met ``criterion``; None if never."""
    return next((row["real_episodes"] for row in rows if row.get(criterion)), None)


def median_or_miss(values: list[int | None]) -> str:
    """Median over seeds, a miss counting as worse than any hit."""
    median = statistics.median(float("inf") if v is None else v for v in values)
    return "not reached" if median == float("inf") else f"{median:g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--budget", type=int, default=2000)
    parser.add_argument("--samplers", default="reinforce,symmetric,supersymmetric")
    args = parser.parse_args()
    print(f"| sampler | median episodes to balanced | median to near-optimal | seeds balanced | seeds near-optimal |")
    print("| --- | --- | --- | --- | --- |")
    for sampler in args.samplers.split(","):
        reached = {criterion: [] for criterion in CRITERIA}
        for seed in range(args.seeds):
            config = TrainConfig(sampler=sampler, seed=seed, budget=args.budget,
                                 popsize=12 if sampler == "supersymmetric" else TrainConfig().popsize)
            rows = train(config, progress=False).rows
            for criterion in CRITERIA:
                reached[criterion].append(first_reached(rows, criterion))
        hits = {c: sum(v is not None for v in reached[c]) for c in CRITERIA}
        print(f"| {sampler} | {median_or_miss(reached['balanced'])} | {median_or_miss(reached['near_optimal'])} "
              f"| {hits['balanced']}/{args.seeds} | {hits['near_optimal']}/{args.seeds} |", flush=True)


if __name__ == "__main__":
    main()
