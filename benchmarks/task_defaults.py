"""`drrl train TASK` with no other flag, then `drrl eval`, on every registered drrl task: the kind of run its defaults
make, the verdict on the best measured centre, the real episodes spent and the wall time.

Runs the installed command as a user would, one task after another pinned to ``--core``, each cut after
``--timeout`` seconds (by SIGTERM: the run checkpoints, and its best centre so far is evaluated and marked as cut).
Writes every row to ``benchmarks/results/task_defaults.json``; ``--table`` prints that file as the Markdown table
BENCHMARKS.md shows.

    python benchmarks/task_defaults.py --core 1 --timeout 150
    python benchmarks/task_defaults.py --tasks cartpole --seeds 0-9 --core 1
    python benchmarks/task_defaults.py --tasks HalfCheetah-v5,MountainCar-v0 --timeout 1200 \\
        --results benchmarks/results/standard_envs.json
    python benchmarks/task_defaults.py --table
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "task_defaults.json"
VERDICT = re.compile(r"^([a-z0-9-]+):\s+(yes|no)$", re.MULTILINE)


def one_task(task: str, core: int, folder: Path, seed: int, timeout: float) -> dict:
    """Train ``task`` with its defaults, evaluate the best measured centre; the row of the table."""
    drrl = Path(sys.executable).with_name("drrl")
    out = folder / f"{task.replace('/', '-')}-{seed}"
    pin = ["taskset", "-c", str(core)]
    row: dict = {"task": task, "seed": seed}
    start = time.perf_counter()
    run = [*pin, drrl, "train", task, "--seed", str(seed), "--quiet", "--out", out]
    training = subprocess.Popen(run, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _, stderr = training.communicate(timeout=timeout)
        cut = False
    except subprocess.TimeoutExpired:  # SIGTERM: the run checkpoints its last whole step, then stops
        training.terminate()
        _, stderr = training.communicate()
        cut = True
    row["wall"] = round(time.perf_counter() - start, 1)
    config = out / "config.json"
    if config.exists():
        row["kind"] = json.loads(config.read_text())["world"]["kind"]
    if not cut and training.returncode != 0:
        row["outcome"] = (stderr.strip().splitlines() or ["failed"])[-1]
        return row
    row["cut"] = cut
    if not (out / "checkpoint.safetensors").exists():
        row["outcome"] = "cut before a checkpoint"
        return row
    lines = (out / "metrics.csv").read_text().splitlines()
    last = dict(zip(lines[0].split(","), lines[-1].split(","), strict=True))
    row["real_episodes"] = int(last["real_episodes"])
    evaluation = subprocess.run([*pin, drrl, "eval", out], capture_output=True, text=True)
    if evaluation.returncode != 0:
        row["outcome"] = "eval failed: " + (evaluation.stderr.strip().splitlines() or ["?"])[-1]
        return row
    evaluated = evaluation.stdout
    row["return"] = float(re.search(r"return (-?[\d.]+)", evaluated).group(1))
    row["verdict"] = dict(VERDICT.findall(evaluated))
    met = row["verdict"] and all(ok == "yes" for ok in row["verdict"].values())
    row["outcome"] = "met" if met else "missed"
    return row


def cpu() -> str:
    """The processor's model name, as Linux reports it."""
    info = Path("/proc/cpuinfo")
    names = re.findall(r"^model name\s*:\s*(.+)$", info.read_text(), re.MULTILINE) if info.exists() else []
    return names[0] if names else platform.processor() or platform.machine()


def one_seed(row: dict) -> str:
    """A row of the table for a task measured with one seed."""
    cut = f"cut after {row['wall']:.0f} s" if row.get("cut") else ""
    if "verdict" not in row:
        return f"{row['outcome']} | — | — | {row['wall']:.0f} s"
    verdict = ", ".join(f"{name} {ok}" for name, ok in row["verdict"].items()) or "none"
    verdict = f"{cut}; its best centre: {verdict}" if cut else verdict
    return f"{verdict} | {row['return']:.1f} | {row['real_episodes']:,} | {row['wall']:.0f} s"


def seeds(rows: list[dict]) -> str:
    """A row of the table for a task measured with several seeds: how many met the verdict, the medians."""
    met = sum(row["outcome"] == "met" for row in rows)
    evaluated = [row for row in rows if "return" in row] or [{"return": float("nan"), "real_episodes": 0}]
    returned = statistics.median(row["return"] for row in evaluated)
    spent = statistics.median(row["real_episodes"] for row in evaluated)
    wall = statistics.median(row["wall"] for row in rows)
    cut = sum(row.get("cut", False) for row in rows)
    said = f"met in {met} of {len(rows)} seeds" + (f" ({cut} cut after {rows[0]['timeout']:.0f} s)" if cut else "")
    return f"{said} | {returned:.1f} | {spent:,.0f} | {wall:.0f} s"


def table(results: dict) -> str:
    """The results file as a Markdown table: a row per task (medians where it was measured with several seeds)."""
    lines = [
        "| task | run | verdict (`drrl eval`, 50 fresh episodes) | return | real episodes | wall |",
        "| --- | --- | --- | --- | ---: | ---: |",
    ]
    by_task: dict[str, list[dict]] = {}
    for row in results["rows"]:
        by_task.setdefault(row["task"], []).append(row)
    for task, rows in by_task.items():
        said = one_seed(rows[0]) if len(rows) == 1 else seeds(rows)
        lines.append(f"| {task} | {rows[0].get('kind', '—')} | {said} |")
    return "\n".join(lines)


def recorded(path: Path, row: dict, first: bool) -> dict:
    """The results file with ``row`` written into it at once (a run cut short loses nothing): the rows of other
    tasks kept, the task's old rows replaced by this invocation's first row of it."""
    from drrl.envs.registry import aliases

    before = json.loads(path.read_text())["rows"] if path.exists() else []
    kept = [old for old in before if old["task"] != row["task"] or not first]
    order = {task: place for place, task in enumerate(aliases())}
    results = {
        "machine": f"{cpu()}, {os.cpu_count()} cores, Python {platform.python_version()}, each run pinned to one core",
        "command": "python benchmarks/task_defaults.py [--tasks TASKS] [--seeds SEEDS] --timeout T; each row has its "
        "date and timeout",
        "rows": sorted([*kept, row], key=lambda row: (order.get(row["task"], len(order)), row["seed"])),
    }
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", help="comma-separated drrl tasks  [default: every registered one]")
    parser.add_argument("--core", type=int, default=1, help="the core every run is pinned to")
    parser.add_argument("--seeds", default="0", help="seeds, as 0-9 or 0,3,5  [default: 0]")
    parser.add_argument("--timeout", type=float, default=150.0, help="seconds a run may take before it is cut")
    parser.add_argument(
        "--results",
        type=Path,
        default=RESULTS,
        help="the results file  [default: benchmarks/results/task_defaults.json]",
    )
    parser.add_argument("--table", action="store_true", help="print the results file as a table, and stop")
    args = parser.parse_args()
    if args.table:
        return print(table(json.loads(args.results.read_text())))
    from drrl.envs.registry import aliases

    tasks = args.tasks.split(",") if args.tasks else list(aliases())
    first, _, last = args.seeds.partition("-")
    chosen = range(int(first), int(last) + 1) if last else [int(seed) for seed in args.seeds.split(",")]
    written: set[str] = set()
    measured = {"date": date.today().isoformat(), "timeout": args.timeout}
    with tempfile.TemporaryDirectory() as folder:
        for task in tasks:
            for seed in chosen:
                row = {**one_task(task, args.core, Path(folder), seed, args.timeout), **measured}
                print(json.dumps(row), flush=True)
                results = recorded(args.results, row, first=task not in written)
                written.add(task)
    print(table(results))


if __name__ == "__main__":
    main()
