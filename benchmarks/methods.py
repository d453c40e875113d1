"""Parameter-space against action-space exploration (thesis 2.2.2, 2.4): real episodes until each of the task's
verdict criteria is first met, for PGPE, the action-space REINFORCE with a baseline and eNAC, and Stable-Baselines3's
PPO as an outside reference, the same measuring for all (``drrl.compare.method_rows``).

    python benchmarks/methods.py --env cartpole --seeds 10 --budget 3000 --workers 2
    python benchmarks/methods.py --env cartpole-po --policy rnn:4 --seeds 10 --budget 3000 --workers 2
    python benchmarks/methods.py --env baxter-reach-right --seeds 5 --budget 800 --eval-episodes 10 --eval-every 2 \\
        --pgpe '{"popsize": 20, "fitness_shaping": "centered_ranks", "sigma_init": 0.05, "sigma_lr": 0.05, \\
                 "center_lr": 0.15}' \\
        --action '{"optimizer": "adam", "center_lr": 0.001, "sigma_init": 0.3}'

PGPE (SyS) runs with drrl's defaults, or the task's suggested settings (``drrl.settings.presets.suggested``), or
``--pgpe``; REINFORCE and eNAC with their own presets or ``--action``, every method with
``--policy`` (PPO with its own networks). The centre is measured on ``--eval-episodes`` episodes after every
``--eval-every`` updates (PPO: after every update). A seed that never met a criterion counts as worse than any
that did. Prints a Markdown table; every run's rows go to ``--out`` as one JSON line as soon as it ends.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

from drrl.compare import ACTION_SPACE, method_config, method_rows
from drrl.envs.registry import lookup
from drrl.settings.presets import suggested
from drrl.training.train import train


def run(job: tuple[str, int, int, dict, dict]) -> dict:
    method, seed, budget, settings, own = job
    torch.set_num_threads(1)
    start = time.perf_counter()
    if own:  # the method's own settings over compare's
        config = method_config(method, seed, budget, settings)
        rows = train(config.updated(**own)).rows
    else:
        rows = method_rows(method, seed, budget, settings)
    measured = [row for row in rows if row["center_return"] == row["center_return"]]
    return {"method": method, "seed": seed, "wall": time.perf_counter() - start, "rows": measured}


def first(rows: list[dict], criterion: str, what: str = "real_episodes") -> float:
    return next((row[what] for row in rows if row.get(criterion) == 1), math.inf)


def show(value: float) -> str:
    return "not reached" if math.isinf(value) else f"{value:g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="cartpole")
    parser.add_argument("--policy", help="every drrl method's policy (default: the method's)")
    parser.add_argument("--methods", default="SyS-PGPE,REINFORCE,eNAC,PPO (SB3)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0, help="run seeds first-seed, first-seed + 1, ...")
    parser.add_argument("--budget", type=int, default=3000)
    parser.add_argument("--pgpe", default="{}", help="PGPE's settings as JSON (default: the task's suggested)")
    parser.add_argument("--action", default="{}", help="REINFORCE's and eNAC's settings as JSON (default: theirs)")
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--eval-every", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("methods.jsonl"))
    parser.add_argument("--table", type=Path, nargs="+", help="only print the table of these runs' JSON lines")
    args = parser.parse_args()
    entry = lookup(args.env)
    if args.table:
        results = [json.loads(line) for path in args.table for line in path.read_text().splitlines() if line]
        print_table(results, entry.criteria())
        return
    task = {"env": args.env, "eval_episodes": args.eval_episodes, "eval_every": args.eval_every}
    if args.policy:
        task["policy"] = args.policy
    pgpe = {**suggested(entry.env_id), **json.loads(args.pgpe), **task}
    pgpe.pop("budget", None)
    action = json.loads(args.action)
    methods = args.methods.split(",")
    jobs = [
        (m, s, args.budget, pgpe if "PGPE" in m else task, action if m in ACTION_SPACE else {})
        for m in methods
        for s in range(args.first_seed, args.first_seed + args.seeds)
    ]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool, args.out.open("w") as out:
        results = []
        for result in pool.map(run, jobs):
            results.append(result)
            out.write(json.dumps(result) + "\n")
            out.flush()
            last = result["rows"][-1]
            print(
                f"{result['method']} seed {result['seed']}: {last['real_episodes']} episodes, centre "
                f"{last['center_return']:.1f}, {result['wall']:.0f} s",
                flush=True,
            )
    seeds = f"seeds {args.first_seed}–{args.first_seed + args.seeds - 1}"
    print(f"\n{entry.env_id}, budget {args.budget}, {seeds}, {time.perf_counter() - start:.0f} s wall")
    print_table(results, entry.criteria())


def print_table(results: list[dict], criteria: tuple[str, ...]) -> None:
    """A Markdown row per method: median real episodes to each criterion, seeds that met it, per seed."""
    header = [f"median episodes to {c}" for c in criteria] + [f"seeds {c}" for c in criteria]
    print("| method | " + " | ".join(header) + " | median steps to " + criteria[0] + " | median wall s | per seed |")
    print("|" + " --- |" * (len(header) + 4))
    for method in dict.fromkeys(r["method"] for r in results):
        runs = sorted((r for r in results if r["method"] == method), key=lambda r: r["seed"])
        firsts = {c: [first(r["rows"], c) for r in runs] for c in criteria}
        steps = [first(r["rows"], criteria[0], "real_steps") for r in runs]
        medians = [show(statistics.median(firsts[c])) for c in criteria]
        counts = [f"{sum(not math.isinf(v) for v in firsts[c])}/{len(runs)}" for c in criteria]
        per_seed = " ".join("/".join(show(firsts[c][i]) for c in criteria) for i in range(len(runs)))
        wall = statistics.median(r["wall"] for r in runs)
        cells = [method, *medians, *counts, show(statistics.median(steps)), f"{wall:.0f}", per_seed]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
