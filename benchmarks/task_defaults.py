"""`drrl train TASK` with no other flag, then `drrl eval`, on every registered drrl task: the kind of run its defaults
make, the verdict on the best measured centre, the real episodes spent and the wall time.

Runs the installed command as a user would, one task after another pinned to ``--core``, each cut after
``--timeout`` seconds (a run cut so is reported as such, with no verdict). Writes every row to
``benchmarks/results/task_defaults.json``; ``--table`` prints that file as the Markdown table BENCHMARKS.md shows.

    python benchmarks/task_defaults.py --core 1 --timeout 150
    python benchmarks/task_defaults.py --tasks cartpole,baxter-reach --core 1
    python benchmarks/task_defaults.py --table
"""

from __future__ import annotations

import argparse
import json
import platform
import re
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
    out = folder / task
    pin = ["taskset", "-c", str(core)]
    row: dict = {"task": task, "seed": seed}
    start = time.perf_counter()
    try:
        trained = subprocess.run(
            [*pin, drrl, "train", task, "--seed", str(seed), "--quiet", "--out", out],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        trained = None
    row["wall"] = round(time.perf_counter() - start, 1)
    config = out / "config.json"
    if config.exists():
        row["kind"] = json.loads(config.read_text())["world"]["kind"]
    if trained is None or trained.returncode != 0:
        row["outcome"] = "cut" if trained is None else (trained.stderr.strip().splitlines() or ["failed"])[-1]
        return row
    lines = (out / "metrics.csv").read_text().splitlines()
    last = dict(zip(lines[0].split(","), lines[-1].split(","), strict=True))
    row["real_episodes"] = int(last["real_episodes"])
    evaluated = subprocess.run([*pin, drrl, "eval", out], capture_output=True, text=True, check=True).stdout
    row["return"] = float(re.search(r"return (-?[\d.]+)", evaluated).group(1))
    row["verdict"] = dict(VERDICT.findall(evaluated))
    row["outcome"] = "met" if row["verdict"] and all(ok == "yes" for ok in row["verdict"].values()) else "missed"
    return row


def table(results: dict) -> str:
    """The results file as a Markdown table: a row per task."""
    lines = [
        "| task | run | verdict (`drrl eval`, 50 fresh episodes) | return | real episodes | wall |",
        "| --- | --- | --- | ---: | ---: | ---: |",
    ]
    for row in results["rows"]:
        if "verdict" in row:
            verdict = ", ".join(f"{name} {ok}" for name, ok in row["verdict"].items()) or "none"
            figures = f"{row['return']:.1f} | {row['real_episodes']:,}"
        else:
            verdict = f"cut after {row['wall']:.0f} s" if row["outcome"] == "cut" else row["outcome"]
            figures = "— | —"
        lines.append(f"| {row['task']} | {row.get('kind', '—')} | {verdict} | {figures} | {row['wall']:.0f} s |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", help="comma-separated drrl tasks  [default: every registered one]")
    parser.add_argument("--core", type=int, default=1, help="the core every run is pinned to")
    parser.add_argument("--seed", type=int, default=0, help="every run's seed")
    parser.add_argument("--timeout", type=float, default=150.0, help="seconds a run may take before it is cut")
    parser.add_argument("--table", action="store_true", help="print the results file as a table, and stop")
    args = parser.parse_args()
    if args.table:
        return print(table(json.loads(RESULTS.read_text())))
    from drrl.envs.registry import aliases

    tasks = args.tasks.split(",") if args.tasks else aliases()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for task in tasks:
            rows.append(one_task(task, args.core, Path(folder), args.seed, args.timeout))
            print(json.dumps(rows[-1]), flush=True)
    # rows of tasks measured before (another --tasks) are kept; each task's newest row wins
    before = json.loads(RESULTS.read_text())["rows"] if RESULTS.exists() else []
    measured = {row["task"]: row for row in [*before, *rows]}
    order = {task: place for place, task in enumerate(aliases())}
    results = {
        "date": date.today().isoformat(),
        "machine": f"{platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, pinned "
        f"to core {args.core}",
        "command": "python benchmarks/task_defaults.py " + " ".join(sys.argv[1:]),
        "timeout": args.timeout,
        "rows": sorted(measured.values(), key=lambda row: order.get(row["task"], len(order))),
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1) + "\n")
    print(table(results))


if __name__ == "__main__":
    main()
