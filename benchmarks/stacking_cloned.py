"""Learning to stack from the scripted stacker's demonstrations (``drrl.training.cloning``): real episodes, real steps
and wall time a run takes, and how often its policy builds the stack.

For each seed, ``drrl train ENV`` with the env's defaults (the settings given override them): the first centre
cloned from the scripted stacker's demonstrations in DAgger rounds, then PGPE; then its best centre measured, as
``drrl eval`` does, on 50 fresh episodes: the share whose stack stood for one second. One row a seed, then medians.

    python benchmarks/stacking_cloned.py --env baxter-stack-end-point --seeds 10
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from drrl.envs.batch import make_batch_env
from drrl.envs.baxter.stacking import stacked_fraction
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.streams import Stream, derive_seed
from drrl.training.loop import measure
from drrl.training.train import build_policy, open_run, train, trained_center

EPISODES = 50


def run_seed(env: str, seed: int, settings: dict, folder: Path) -> dict:
    config = TrainConfig(env=env, seed=seed, **settings)
    start = time.perf_counter()
    counters = train(config, folder)
    wall = time.perf_counter() - start
    config, checkpoint = open_run(RunFolder(folder))
    episodes = make_batch_env(env, EPISODES, config.engine)
    policy = build_policy(config, episodes)
    center = trained_center(checkpoint, policy)
    result = measure(policy, center, episodes, config.max_steps, derive_seed(seed, 0, Stream.BENCHMARKING))
    episodes.close()
    return {
        "seed": seed,
        "stacked": stacked_fraction(result.episode_returns, result.terminated),
        "real_episodes": counters.real_episodes,
        "real_steps": counters.real_steps,
        "wall_s": round(wall, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="baxter-stack-end-point")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--settings", type=json.loads, default={}, help="TrainConfig settings as JSON")
    args = parser.parse_args()
    print("| seed | stood (50 fresh episodes) | real episodes | real steps | wall s |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            row = run_seed(args.env, seed, args.settings, Path(scratch) / f"seed{seed}")
            rows.append(row)
            print(
                f"| {seed} | {row['stacked']:.0%} | {row['real_episodes']} | {row['real_steps']:,} | {row['wall_s']} |",
                flush=True,
            )
    median = {key: statistics.median(row[key] for row in rows) for key in ("stacked", "real_episodes", "wall_s")}
    print(f"median: stood {median['stacked']:.0%}, {median['real_episodes']} real episodes, {median['wall_s']} s")


if __name__ == "__main__":
    main()
