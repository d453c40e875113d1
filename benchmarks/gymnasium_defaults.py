"""`drrl train ENV` with no other flag, then `drrl eval`, on Gymnasium's envs: what the defaults reach, and at what
cost in real episodes, real steps and wall time.

Runs the installed command as a user would, ``--jobs`` runs at a time (each pinned to its own core), and reads the
run folders. The solved levels are the ones drrl aims its defaults at.

    python benchmarks/gymnasium_defaults.py --jobs 2
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


def one_run(env: str, core: int, folder: Path) -> dict:
    drrl = Path(sys.executable).with_name("drrl")
    out = folder / env
    pin = ["taskset", "-c", str(core)]
    start = time.perf_counter()
    subprocess.run([*pin, drrl, "train", env, "--quiet", "--out", out], check=True, capture_output=True)
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
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default=",".join(TARGETS))
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    envs = args.envs.split(",")
    free = queue.Queue()
    for core in range(args.jobs):
        free.put(core)

    def on_a_free_core(env: str) -> dict:
        core = free.get()
        try:
            return one_run(env, core, Path(folder))
        finally:
            free.put(core)

    with tempfile.TemporaryDirectory() as folder, ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(on_a_free_core, envs))
    print("| env | engine | real episodes | real steps | wall | `drrl eval` (50 episodes) | solved level | met |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |")
    for r in results:
        target = TARGETS.get(r["env"])
        met = "—" if target is None else "yes" if r["eval"] >= target else "no"
        print(
            f"| {r['env']} | {r['engine']} | {r['episodes']:,} | {r['steps']:,} | {r['wall']:.0f} s | "
            f"{r['eval']:.1f} | {target} | {met} |"
        )


if __name__ == "__main__":
    main()
