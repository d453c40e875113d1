"""The transfer gap (thesis 5.2.3, 6.2): a policy trained in drrl's nominal Baxter, measured on stand-ins for the real
robot (``drrl.envs.baxter.standin``: masses and damping off by up to ±20 %, commands a period late and lagging, noisy
joint sensors).

For each seed, ``drrl.training.train.train`` trains the one-arm fixed-target reach (the Baxter tutorial's model-free
settings) in the nominal simulator; its best measured centre then runs ``--episodes`` fresh episodes on the nominal
robot and on each of ``--robots`` stand-ins (counted apart from training). Prints the fraction reached (every
end-point within 0.05 m at the end, nothing failed) and the fraction failed, per seed and robot, then medians.

    python benchmarks/transfer_gap.py --seeds 3 --robots 3
    python benchmarks/transfer_gap.py --seeds 3 --first-seed 2 --robots 0 --ablate 1   # one difference at a time
"""

from __future__ import annotations

import argparse
import statistics
import tempfile

import numpy as np
import torch
from baxter_reach import final_distances

from drrl.envs.batch import make_batch_env
from drrl.envs.baxter.task import reach_fraction
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.train import build_policy, train


def measure(policy, center: torch.Tensor, options: dict, episodes: int) -> tuple[float, float]:
    """(fraction reached, fraction failed) of ``center`` over ``episodes`` fresh episodes on the env ``options``
    make."""
    env = make_batch_env("baxter-reach-right", episodes, options=options)
    try:
        distance, failed = final_distances(policy, center, env, seed=10_000)
    finally:
        env.close()
    return reach_fraction(torch.as_tensor(distance), torch.as_tensor(failed)), float(np.mean(failed))


NONE = {"mass_error": 0.0, "damping_error": 0.0, "delay": 0, "lag": 0.0, "angle_noise": 0.0, "velocity_noise": 0.0}
ONE_AT_A_TIME = {  # each of the stand-in's differences alone, at its default size
    "masses and damping": {"mass_error": 0.2, "damping_error": 0.2},
    "delay": {"delay": 1},
    "lag": {"lag": 0.05},
    "sensor noise": {"angle_noise": 0.005, "velocity_noise": 0.05},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--robots", type=int, default=3, help="stand-ins, robot seeds 0, 1, ...")
    parser.add_argument("--budget", type=int, default=400)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--ablate", type=int, help="also robot ABLATE with one of its differences at a time")
    args = parser.parse_args()
    torch.set_num_threads(1)
    robots = {"nominal": {}} | {f"stand-in {r}": {"stand_in": {"seed": r}} for r in range(args.robots)}
    if args.ablate is not None:
        for name, difference in ONE_AT_A_TIME.items():
            robots[f"{name} only"] = {"stand_in": NONE | difference | {"seed": args.ablate}}
    print("| seed | " + " | ".join(f"{name}: reached / failed" for name in robots) + " |")
    print("| --- |" + " --- |" * len(robots))
    results: dict[str, list[float]] = {name: [] for name in robots}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        config = TrainConfig(
            env="baxter-reach-right",
            popsize=20,
            fitness_shaping="centered_ranks",
            sigma_init=0.05,
            sigma_lr=0.05,
            center_lr=0.15,
            budget=args.budget,
            eval_episodes=10,
            seed=seed,
        )
        with tempfile.TemporaryDirectory() as folder:
            train(config, out=f"{folder}/run", progress=False)
            center = RunFolder(f"{folder}/run").load_checkpoint()["best_center"]
        probe = make_batch_env("baxter-reach-right", 1)
        policy = build_policy(config, probe)
        probe.close()
        cells = []
        for name, options in robots.items():
            reached, failed = measure(policy, center, options, args.episodes)
            results[name].append(reached)
            cells.append(f"{reached:.2f} / {failed:.2f}")
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)
    print(
        "\nmedian reached: " + ", ".join(f"{name} {statistics.median(values):.2f}" for name, values in results.items())
    )


if __name__ == "__main__":
    main()
