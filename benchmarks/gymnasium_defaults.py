"""`drrl train ENV` with no other flag, then `drrl eval`, on Gymnasium's envs: what the defaults reach, and at what
cost in real episodes, real steps and wall time.

Runs the installed command as a user would, one run at a time on each of ``--cores`` (each run pinned to its
core), and reads the run folders: the whole run, what ``drrl eval`` gives its best measured centre, and where a
measured centre first reached the solved level (real episodes, real steps and wall time until then, the centre
measured on 50 episodes, as ``benchmarks/ppo_zoo.py`` measures PPO). The solved levels are the ones drrl aims its
defaults at.

    python benchmarks/gymnasium_defaults.py --cores 0,1
    python benchmarks/gymnasium_defaults.py --envs Hopper-v5 --cores 1 --seed 2
"""

from __future__ import annotations

import argparse
import json
import queue
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

TARGETS = {
    "Pendulum-v1": -200,
    "Acrobot-v1": -100,
    "MountainCarContinuous-v0": 90,
    "InvertedDoublePendulum-v5": 9000,
    "Reacher-v5": -5,
    "Hopper-v5": 2500,
}


def first_at_level(metrics: Path, level: float) -> dict | None:
    """The first metrics row whose measured centre reached ``level``: real episodes, real steps, wall seconds."""
    lines = metrics.read_text().splitlines()
    for line in lines[1:]:
        row = dict(zip(lines[0].split(","), line.split(","), strict=True))
        if row["center_return"] not in ("", "nan") and float(row["center_return"]) >= level:
            return {key: float(row[key]) for key in ("real_episodes", "real_steps", "wall_time")}
    return None


def one_run(env: str, core: int, folder: Path, seed: int) -> dict:
    drrl = Path(sys.executable).with_name("drrl")
    out = folder / env
    pin = ["taskset", "-c", str(core)]
    start = time.perf_counter()
    train = [*pin, drrl, "train", env, "--seed", str(seed), "--quiet", "--out", out]
    subprocess.run(train, check=True, capture_output=True)
    wall = time.perf_counter() - start
    evaluated = subprocess.run([*pin, drrl, "eval", out], check=True, capture_output=True, text=True).stdout
    lines = (out / "metrics.csv").read_text().splitlines()
    row = dict(zip(lines[0].split(","), lines[-1].split(","), strict=True))
    config = json.loads((out / "config.json").read_text())
    eval_return = float(re.search(r"return (-?[\d.]+)", evaluated).group(1))
    return {
        "env": env,
        "engine": config["engine"],
        "episodes": int(row["real_episodes"]),
        "steps": int(row["real_steps"]),
        "wall": wall,
        "eval": eval_return,
        "solved": first_at_level(out / "metrics.csv", TARGETS[env]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default=",".join(TARGETS))
    parser.add_argument("--cores", default="0,1", help="comma-separated cores, one run at a time on each")
    parser.add_argument("--seed", type=int, default=0, help="every run's seed")
    args = parser.parse_args()
    envs = args.envs.split(",")
    free = queue.Queue()
    cores = [int(core) for core in args.cores.split(",")]
    for core in cores:
        free.put(core)

    def on_a_free_core(env: str) -> dict:
        core = free.get()
        try:
            return one_run(env, core, Path(folder), args.seed)
        finally:
            free.put(core)

    with tempfile.TemporaryDirectory() as folder, ThreadPoolExecutor(len(cores)) as pool:
        results = list(pool.map(on_a_free_core, envs))
    print(
        "| env | engine | real episodes | real steps | wall | `drrl eval` (50 episodes) | solved level | met | "
        "first measured at the level: real episodes / real steps / wall |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | --- | --- |")
    for r in results:
        target = TARGETS[r["env"]]
        met = "yes" if r["eval"] >= target else "no"
        solved = r["solved"]
        first = (
            "never"
            if solved is None
            else f"{solved['real_episodes']:,.0f} / {solved['real_steps']:,.0f} / {solved['wall_time']:.0f} s"
        )
        print(
            f"| {r['env']} | {r['engine']} | {r['episodes']:,} | {r['steps']:,} | {r['wall']:.0f} s | "
            f"{r['eval']:.1f} | {target} | {met} | {first} |"
        )


if __name__ == "__main__":
    main()
