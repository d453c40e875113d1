"""Benchmark scripts read what runs write, and BENCHMARKS.md shows what their results files hold."""

import json
import runpy
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from drrl.cli import main

BENCHMARKS = Path(__file__).parent.parent / "benchmarks"


def model_based_run(out: Path, seed: int) -> None:
    settings = [
        "--budget",
        "2",
        "--generations-per-iteration",
        "1",
        "--model-hidden",
        "8",
        "--eval-episodes",
        "2",
        "--quiet",
    ]
    result = CliRunner().invoke(
        main, ["train", "cartpole", "--model-based", *settings, "--seed", str(seed), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output


@pytest.mark.slow
def test_world_models_fits_on_one_runs_episodes_and_measures_on_anothers(tmp_path):
    for seed in (0, 1):
        model_based_run(tmp_path / f"run{seed}", seed)
    variants = '{"lstm 8": {"model_kind": "lstm", "hidden": [8], "members": 1, "max_updates": 5}}'
    script = str(BENCHMARKS / "world_models.py")
    result = subprocess.run(
        [sys.executable, script, str(tmp_path / "run0"), str(tmp_path / "run1"), "--variants", variants],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "2 training episodes" in result.stdout and "2 held-out" in result.stdout
    row = next(line for line in result.stdout.splitlines() if line.startswith("| lstm 8 |"))
    errors = [float(cell) for cell in row.strip("| ").split(" | ")[2:]]
    assert len(errors) == 5 and all(error > 0 for error in errors)


@pytest.mark.parametrize("results", ["task_defaults.json", "standard_envs.json"])
def test_benchmarks_md_shows_each_task_table_as_its_results_file_holds_it(results):
    table = runpy.run_path(str(BENCHMARKS / "task_defaults.py"))["table"]
    measured = json.loads((BENCHMARKS / "results" / results).read_text())
    assert table(measured) in (BENCHMARKS.parent / "BENCHMARKS.md").read_text()
