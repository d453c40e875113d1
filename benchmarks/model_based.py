"""Real training episodes until the centre policy is balanced / near-optimal on the thesis cart-pole (5.1), or the
swing-up is solved, with model-based PGPE (drrl.training.model_based) at its defaults; with --quality, the
model-quality plot.

Every iteration measures the centre policy on 50 fresh real episodes (counted apart from training). Prints one row
per seed, then medians over seeds; a seed that never gets there counts as worse than any that does.

    python benchmarks/model_based.py --seeds 10
    python benchmarks/model_based.py --env cartpole-swingup --seeds 10
    python benchmarks/model_based.py --seeds 1 --quality model_quality.png
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from sample_efficiency import first_reached, median_or_miss

from drrl.envs.registry import lookup
from drrl.models import EpisodeBuffer
from drrl.models.quality import model_quality_report
from drrl.settings import ModelBasedSettings, TrainConfig, load_config_file
from drrl.training.loop import run
from drrl.training.train import prepare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--config",
        type=Path,
        help="TOML or JSON file of settings, as `drrl train --config` reads (the options below override it)",
    )
    parser.add_argument("--env", help="[default: cartpole]")
    parser.add_argument("--policy", help="[default: the env's model-based default]")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--budget", type=int, help="real training episodes [default: the env's model-based default]")
    parser.add_argument("--model-based", default="{}", help="JSON of ModelBasedSettings fields to change")
    parser.add_argument("--search", default="{}", help="JSON of TrainConfig fields to change")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (tiny matrices: 1 is fastest)")
    parser.add_argument("--rows", help="append every run's metrics rows to this JSON-lines file")
    parser.add_argument("--quality", help="write the k-step model-quality plot of the first seed's data here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    settings = {
        "env": "cartpole",
        **(load_config_file(args.config) if args.config else {}),
        **{name: value for name in ("env", "policy", "budget") if (value := getattr(args, name)) is not None},
        **json.loads(args.search),
    }
    model_settings = {**(settings.pop("model_based", None) or {}), **json.loads(args.model_based)}
    criteria = list(lookup(settings["env"]).criteria())
    reached = {criterion: [] for criterion in criteria}
    walls, cpus, finals = [], [], []
    print(
        "| seed | " + "".join(f"episodes to {c} | " for c in criteria) + "best centre return | final centre return "
        "| wall s | cpu s |"
    )
    print("| --- " * (len(criteria) + 5) + "|")
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        config = TrainConfig.model_validate({**settings, "seed": seed, "model_based": model_settings})
        wall, cpu = time.perf_counter(), time.process_time()
        setup = prepare(config)
        result = run(setup)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
        finals.append(result.rows[-1]["center_return"])
        if args.rows:
            with open(args.rows, "a") as handle:
                handle.write(json.dumps({"seed": seed, "env": config.env, "rows": result.rows}) + "\n")
        for criterion in criteria:
            reached[criterion].append(first_reached(result.rows, criterion))
        best = max(row["center_return"] for row in result.rows)
        print(
            f"| {seed} | " + "".join(f"{reached[c][-1]} | " for c in criteria) + f"{best:.1f} | {finals[-1]:.1f} "
            f"| {walls[-1]:.0f} | {cpus[-1]:.0f} |",
            flush=True,
        )
        if args.quality and seed == args.first_seed:
            quality_plot(setup.world.buffer, args.quality, seed, config.model_based)
    print()
    for criterion in criteria:
        hits = sum(v is not None for v in reached[criterion])
        print(f"median real episodes to {criterion}: {median_or_miss(reached[criterion])} ({hits}/{args.seeds} seeds)")
    print(
        f"median final centre return {statistics.median(finals):.1f}; median wall time "
        f"{statistics.median(walls):.0f} s, cpu time {statistics.median(cpus):.0f} s per run "
        f"({torch.get_num_threads()} torch thread(s))"
    )


def quality_plot(buffer: EpisodeBuffer, path: str, seed: int, settings: ModelBasedSettings) -> None:
    """Hold out every fourth real episode of a run and compare the model variants on them."""
    episodes = buffer.episodes
    held_out = EpisodeBuffer(episodes[3::4])
    training = EpisodeBuffer([e for i, e in enumerate(episodes) if i % 4 != 3])
    curves = model_quality_report(
        training,
        held_out,
        path,
        max_k=50,
        hidden=settings.hidden,
        settings=settings.fit_settings(True, learn_reward=False),
        seed=seed,
    )
    for label, errors in curves.items():
        print(f"{label}: median k-step error at k = 1, 10, 25, 50: {np.round(errors[[0, 9, 24, 49]], 3).tolist()}")
    print(f"model-quality plot: {path}")


if __name__ == "__main__":
    main()
