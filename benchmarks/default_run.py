"""Wall time of `drrl train cartpole` with its defaults: until the centre policy is first balanced, and in all.

Runs the installed command as a user would (start-up and imports included), for a few seeds, and reads the time of
the first balanced generation from metrics.csv (measured from the start of training) plus the start-up time.

    python benchmarks/default_run.py --seeds 5
"""

from __future__ import annotations

import argparse
import csv
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def one_run(seed: int, folder: Path) -> tuple[float, float | None, int | None]:
    """(total seconds, seconds until first balanced, real episodes until first balanced) of one default run."""
    drrl = Path(sys.executable).with_name("drrl")
    out = folder / f"seed{seed}"
    start = time.perf_counter()
    subprocess.run(
        [drrl, "train", "cartpole", "--seed", str(seed), "--quiet", "--out", str(out)], check=True, capture_output=True
    )
    total = time.perf_counter() - start
    with (out / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    startup = total - float(rows[-1]["wall_time"])  # process start, imports and set-up before the first generation
    first = next((row for row in rows if row["balanced"] == "1"), None)
    if first is None:
        return total, None, None
    return total, startup + float(first["wall_time"]), int(first["real_episodes"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp())
    try:
        results = [one_run(seed, folder) for seed in range(args.seeds)]
    finally:
        shutil.rmtree(folder)
    for seed, (total, balanced_at, episodes) in enumerate(results):
        print(
            f"seed {seed}: whole run {total:.1f} s; balanced after {balanced_at and round(balanced_at, 1)} s "
            f"({episodes} real episodes)"
        )
    reached = [r[1] for r in results if r[1] is not None]
    print(
        f"median whole run {statistics.median(r[0] for r in results):.1f} s; median time to balanced "
        f"{statistics.median(reached) if reached else float('nan'):.1f} s ({len(reached)}/{args.seeds} balanced)"
    )


if __name__ == "__main__":
    main()
