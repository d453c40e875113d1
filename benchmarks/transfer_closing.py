"""Closing the transfer gap with a few stand-in episodes (thesis 5.2.3, 6.2).

For each seed: model-based PGPE learns the one-arm fixed-target reach in drrl's nominal Baxter at its model-based
defaults (``drrl train baxter-reach-right --model-based``); its best measured centre is measured on the stand-in for
the real robot (``baxter-reach-right-standin``, robot 0: masses and damping off, commands a period late and lagging,
noisy sensors): *before*. A model-based run on the stand-in then starts from that run's policy and world model
(``start_from``) and spends ``--budget`` stand-in episodes: its last centre and its best measured one, measured on
the stand-in: *after*. Beside it, the same run on the stand-in without the simulator's start: *from scratch*.
Every measurement is ``--episodes`` fresh stand-in episodes, counted apart from training; the runs' own measuring
(10 episodes an iteration) is counted apart too.

    python benchmarks/transfer_closing.py --seeds 5
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import torch
from transfer_gap import measure

from drrl.envs.batch import make_batch_env
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.train import build_policy, train

STAND_IN = {"stand_in": {"seed": 0}}  # the registered stand-in's robot


def model_based_run(env: str, seed: int, budget: int | None, out: Path, start_from: Path | None = None) -> dict:
    """Train a model-based run at the env's defaults into ``out``; its checkpoint."""
    settings = {"env": env, "model_based": {}, "seed": seed, "eval_episodes": 10}
    if budget is not None:
        settings["budget"] = budget
    if start_from is not None:
        settings["start_from"] = str(start_from)
    train(TrainConfig.model_validate(settings), out=out)
    return RunFolder(out).load_checkpoint()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--budget", type=int, default=10, help="stand-in episodes of the closing runs")
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    torch.set_num_threads(1)
    probe = make_batch_env("baxter-reach-right", 1)
    policy = build_policy(TrainConfig.model_validate({"env": "baxter-reach-right", "model_based": {}}), probe)
    probe.close()
    columns = ("simulator, nominal", "simulator, stand-in", "transferred, last", "transferred, best", "scratch, last")
    print("| seed | " + " | ".join(f"{name}: reached / failed" for name in columns) + " | stand-in episodes |")
    print("| --- |" + " --- |" * (len(columns) + 1))
    results: dict[str, list[float]] = {name: [] for name in columns}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        with tempfile.TemporaryDirectory() as folder:
            simulated = model_based_run("baxter-reach-right", seed, None, Path(folder) / "sim")
            transferred = model_based_run(
                "baxter-reach-right-standin", seed, args.budget, Path(folder) / "transfer", Path(folder) / "sim"
            )
            scratch = model_based_run("baxter-reach-right-standin", seed, args.budget, Path(folder) / "scratch")
        measured = {
            "simulator, nominal": measure(policy, simulated["best_center"], {}, args.episodes),
            "simulator, stand-in": measure(policy, simulated["best_center"], STAND_IN, args.episodes),
            "transferred, last": measure(policy, transferred["center"], STAND_IN, args.episodes),
            "transferred, best": measure(policy, transferred["best_center"], STAND_IN, args.episodes),
            "scratch, last": measure(policy, scratch["center"], STAND_IN, args.episodes),
        }
        for name, (reached, _) in measured.items():
            results[name].append(reached)
        cells = [f"{reached:.2f} / {failed:.2f}" for reached, failed in measured.values()]
        print(f"| {seed} | " + " | ".join(cells) + f" | {transferred['real_episodes']} |", flush=True)
    print("\nmedian reached: " + ", ".join(f"{name} {statistics.median(v):.2f}" for name, v in results.items()))


if __name__ == "__main__":
    main()
