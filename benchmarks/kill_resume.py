"""Kill-and-resume: `drrl train` killed with SIGKILL at random moments, resumed, compared with an uninterrupted run.

Each trial starts `drrl train` in a process, kills it (SIGKILL: no handler runs, nothing is flushed) at a moment
drawn uniformly over the training part of an uninterrupted run's duration, resumes it with `drrl train --resume`,
and compares the finished run folder with the uninterrupted one: metrics.csv (all columns but the timings) and every
value and tensor of the final checkpoint must be identical.

    python benchmarks/kill_resume.py --trials 20
    python benchmarks/kill_resume.py --trials 20 --model-based
"""

from __future__ import annotations

import argparse
import csv
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from drrl.runs import RunFolder

DRRL = str(Path(sys.executable).with_name("drrl"))
TIMINGS = ("wall_time", "fit_time", "search_time")  # seconds: the one thing a resumed run does not repeat
MODEL_FREE = [
    "cartpole",
    "--budget",
    "400",
    "--popsize",
    "8",
    "--eval-episodes",
    "10",
    "--checkpoint-every",
    "5",
    "--seed",
    "7",
    "--quiet",
]
MODEL_BASED = [
    "cartpole",
    "--model-based",
    "--budget",
    "12",
    "--popsize",
    "10",
    "--episodes-per-candidate",
    "4",
    "--generations-per-iteration",
    "20",
    "--model-hidden",
    "32",
    "--eval-episodes",
    "10",
    "--seed",
    "7",
    "--quiet",
]


def metrics(out: Path) -> list[dict[str, str]]:
    with (out / "metrics.csv").open() as handle:
        return [{k: v for k, v in row.items() if k not in TIMINGS} for row in csv.DictReader(handle)]


def flatten(value, prefix=""):
    """(path, value) pairs of a nested checkpoint, tensors as (dtype, shape, bytes)."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from flatten(item, f"{prefix}/{key}")
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            yield from flatten(item, f"{prefix}/{index}")
    elif isinstance(value, torch.Tensor):
        yield prefix, (str(value.dtype), tuple(value.shape), value.contiguous().view(-1).view(torch.uint8).tolist())
    elif not prefix.endswith(TIMINGS):
        yield prefix, value


def identical(a: Path, b: Path) -> bool:
    states = [dict(flatten(RunFolder(out).load_checkpoint())) for out in (a, b)]
    return metrics(a) == metrics(b) and states[0] == states[1]


def trial(settings: list[str], out: Path, kill_after: float) -> tuple[int, int]:
    """Kill a run ``kill_after`` seconds into its training, resume it; (rows of metrics written before the kill,
    the checkpoint's step)."""
    process = subprocess.Popen(
        [DRRL, "train", *settings, "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    while not (out / "checkpoint.safetensors").exists():  # written once the run has been set up
        time.sleep(0.002)
    time.sleep(kill_after)
    process.kill()
    process.wait()
    written = len(metrics(out)) if (out / "metrics.csv").exists() else 0
    saved = RunFolder(out).load_checkpoint()["iteration"]
    subprocess.run([DRRL, "train", "--resume", str(out), "--quiet"], check=True, stdout=subprocess.DEVNULL)
    return written, saved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0, help="seed of the kill moments")
    parser.add_argument(
        "--model-based",
        action="store_true",
        help="model-based runs (6 iterations) instead of model-free ones (50 generations)",
    )
    args = parser.parse_args()
    settings = MODEL_BASED if args.model_based else MODEL_FREE
    folder = Path(tempfile.mkdtemp(prefix="drrl-kill-resume-"))
    reference = folder / "uninterrupted"
    subprocess.run([DRRL, "train", *settings, "--out", str(reference)], check=True, stdout=subprocess.DEVNULL)
    training = float(list(csv.DictReader((reference / "metrics.csv").open()))[-1]["wall_time"])
    steps = len(metrics(reference))
    print(f"drrl train {' '.join(settings)}: {steps} steps, training part {training:.2f} s uninterrupted")
    moments = random.Random(args.seed)
    same = 0
    for number in range(1, args.trials + 1):
        kill_after = moments.uniform(0, training)
        written, saved = trial(settings, folder / f"trial{number}", kill_after)
        ok = identical(folder / f"trial{number}", reference)
        same += ok
        print(
            f"trial {number:2}: SIGKILL {kill_after:5.2f} s into training, after {written:2} rows of metrics; "
            f"checkpoint at step {saved:2}, {written - saved} row(s) dropped on resume; "
            f"{'identical' if ok else 'DIFFERENT'}"
        )
    print(
        f"{same}/{args.trials} resumed runs bit-identical to the uninterrupted run (timings aside); "
        f"run folders in {folder}"
    )


if __name__ == "__main__":
    main()
