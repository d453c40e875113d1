"""Fingerprints of reference runs, to show that a change of the code's shape leaves every run's numbers as they were.

Trains each reference run (below) into a fresh folder and records, per run, the SHA-256 of metrics.csv without its
clock columns (wall_time, fit_time, search_time: seconds, which differ from run to run) and of every checkpoint
tensor's bytes, and of each entry of the checkpoint's other state (counters, best return, kind, the search's and the
world's plain values, by their dotted path) as JSON, without its wall time and its record of the settings, whose form
may change while the run stays the same. ``--check FILE`` compares against a file an earlier ``--record FILE`` wrote
and lists every difference; exit status 1 if there is one.

    python benchmarks/same_runs.py --record before.json
    python benchmarks/same_runs.py --check before.json
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from safetensors import safe_open

RUNS = {
    "cartpole": ["cartpole", "--seed", "0"],
    "cartpole-model-based": ["cartpole", "--model-based", "--seed", "0"],
    "swingup-model-based": ["cartpole-swingup", "--model-based", "--budget", "6", "--seed", "0"],
    "cartpole-cmaes": ["cartpole", "--search", "cmaes", "--budget", "200", "--seed", "0"],
    "cartpole-reinforce": ["cartpole", "--search", "reinforce", "--budget", "200", "--seed", "0"],
    "stack-end-point": ["baxter-stack-end-point", "--budget", "80", "--seed", "0"],
    "pixels-model-based": ["cartpole-pixels", "--model-based", "--budget", "24", "--seed", "0"],
}
UNFINGERPRINTED = ("wall_time", "config", "metrics")  # the clock, the settings' form, the digest of metrics.csv (clock)


def fingerprint(folder: Path) -> dict:
    """What a run folder's numbers are, wall time and the settings' form aside."""
    with (folder / "metrics.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    text = io.StringIO()
    writer = csv.writer(text)
    columns = [name for name in rows[0] if not name.endswith("_time")]
    writer.writerows([columns, *([row[name] for name in columns] for row in rows)])
    with safe_open(folder / "checkpoint.safetensors", framework="pt") as handle:
        tensors = {
            key: hashlib.sha256(handle.get_tensor(key).contiguous().numpy().tobytes()).hexdigest()
            for key in handle.keys()  # noqa: SIM118 (not iterable)
        }
        state = json.loads(handle.metadata()["state"])
    kept = [item for item in state["items"] if item[0] not in UNFINGERPRINTED]
    return {
        "metrics": hashlib.sha256(text.getvalue().encode()).hexdigest(),
        "rows": len(rows),
        "tensors": tensors,
        "state": {path: hashlib.sha256(leaf.encode()).hexdigest() for path, leaf in leaves(kept)},
    }


def leaves(items: list, prefix: str = "") -> list[tuple[str, str]]:
    """The checkpoint state's entries by their dotted path (``world.model``), each leaf as JSON."""
    found = []
    for key, value in items:
        path = f"{prefix}{key}"
        nested = value.get("items") if isinstance(value, dict) else None
        if isinstance(nested, list) and all(isinstance(item, list) and len(item) == 2 for item in nested):
            found += leaves(nested, path + ".")
        else:
            found.append((path, json.dumps(value, sort_keys=True)))
    return found


def train(name: str, arguments: list[str], root: Path) -> dict:
    out = root / name
    command = [
        sys.executable,
        "-c",
        "from drrl.cli import main; main()",
        "train",
        *arguments,
        "--out",
        str(out),
        "--quiet",
    ]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return fingerprint(out)


def differences(before: dict, after: dict) -> list[str]:
    found = []
    for name in before.keys() | after.keys():
        old, new = before.get(name), after.get(name)
        if old is None or new is None:
            found.append(f"{name}: only {'after' if old is None else 'before'}")
            continue
        for part in ("metrics", "rows"):
            if old[part] != new[part]:
                found.append(f"{name}: {part} differs")
        for side, keys in (
            ("before", old["state"].keys() - new["state"]),
            ("after", new["state"].keys() - old["state"]),
        ):
            found += [f"{name}: state {key} only {side}" for key in sorted(keys)]
        found += [
            f"{name}: state {key} differs"
            for key in sorted(old["state"].keys() & new["state"].keys())
            if old["state"][key] != new["state"][key]
        ]
        renamed = set(old["tensors"]) ^ set(new["tensors"])
        if renamed:
            found.append(f"{name}: tensors only on one side: {sorted(renamed)}")
        found += [
            f"{name}: tensor {key} differs"
            for key in sorted(set(old["tensors"]) & set(new["tensors"]))
            if old["tensors"][key] != new["tensors"][key]
        ]
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--record", type=Path, help="write the fingerprints here")
    which.add_argument("--check", type=Path, help="compare with the fingerprints in this file")
    parser.add_argument("--runs", default=",".join(RUNS), help=f"comma-separated, of: {', '.join(RUNS)}")
    args = parser.parse_args()
    names = args.runs.split(",")
    with tempfile.TemporaryDirectory() as root:
        prints = {}
        for name in names:
            prints[name] = train(name, RUNS[name], Path(root))
            print(f"{name}: {prints[name]['rows']} rows, {len(prints[name]['tensors'])} tensors", flush=True)
    if args.record:
        args.record.write_text(json.dumps(prints, indent=1, sort_keys=True) + "\n")
        return
    before = {name: value for name, value in json.loads(args.check.read_text()).items() if name in names}
    found = differences(before, prints)
    print("\n".join(found) or f"all {len(names)} runs identical")
    sys.exit(1 if found else 0)


if __name__ == "__main__":
    main()
