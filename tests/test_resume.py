"""Exact resume: a run killed at a random moment and resumed ends with the metrics and state of an uninterrupted run."""

import csv
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from drrl.cli import main
from drrl.runs import RunFolder
from drrl.training.train import prepare_resume

RUN = ["cartpole", "--popsize", "8", "--eval-episodes", "4", "--seed", "4", "--quiet"]
SETTINGS = [*RUN, "--budget", "128"]  # 16 generations


def drrl(*args) -> list[str]:
    return [str(Path(sys.executable).with_name("drrl")), *args]


def rows(out: Path) -> list[dict[str, str]]:
    """metrics.csv without the wall_time column, the one that cannot repeat."""
    with (out / "metrics.csv").open() as handle:
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(handle)]


def same_state(a: Path, b: Path) -> bool:
    first, second = RunFolder(a).load_checkpoint(), RunFolder(b).load_checkpoint()
    search_a, search_b = first.pop("search"), second.pop("search")
    first.pop("wall_time"), second.pop("wall_time")
    first.pop("config"), second.pop("config")  # the runs compared differ in checkpoint_every alone
    first.pop("metrics"), second.pop("metrics")  # the digest of metrics.csv, whose wall_time column differs
    return (
        all(
            torch.equal(search_a[k], search_b[k])
            if isinstance(search_a[k], torch.Tensor)
            else search_a[k] == search_b[k]
            for k in search_a
            if k != "optimizer_state"
        )
        and torch.equal(first.pop("center"), second.pop("center"))
        and torch.equal(first.pop("best_center"), second.pop("best_center"))
        and first == second
    )


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("whole") / "run"
    result = CliRunner().invoke(main, ["train", *SETTINGS, "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def start_and_stop(out: Path, how: signal.Signals, extra_delay: float, *options) -> tuple[int, str]:
    """Start `drrl train` in a process, wait until it has written two generations' metrics and ``extra_delay``
    seconds more, then signal it; its exit code and error output."""
    process = subprocess.Popen(
        drrl("train", *SETTINGS, *options, "--out", str(out)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    metrics = out / "metrics.csv"
    while process.poll() is None and not (metrics.exists() and len(metrics.read_text().splitlines()) > 2):
        time.sleep(0.01)
    time.sleep(extra_delay)
    process.send_signal(how)
    _, errors = process.communicate(timeout=60)
    return process.returncode, errors


@pytest.mark.slow
def test_sigkill_at_a_random_moment_then_resume_gives_the_uninterrupted_run(tmp_path, uninterrupted):
    delay = random.Random().uniform(0, 0.4)
    out = tmp_path / "run"
    start_and_stop(out, signal.SIGKILL, delay, "--checkpoint-every", "4")
    written, saved = len(rows(out)), RunFolder(out).load_checkpoint()["iteration"]
    assert saved <= written and saved % 4 == 0, (delay, written, saved)
    result = CliRunner().invoke(main, ["train", "--resume", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    assert f"resuming {out} at generation {saved + 1} of 16" in result.output or saved == 16
    assert rows(out) == rows(uninterrupted), f"killed {delay:.3f} s after generation 2"
    assert same_state(out, uninterrupted)


def signal_after_three_rows(out: Path, how: signal.Signals) -> None:
    """Send ``how`` to this process once the run in ``out`` has written three rows of metrics, so that the state of
    generation 2 at least is whole (a generation's row is written just before its state is taken)."""
    metrics, deadline = out / "metrics.csv", time.monotonic() + 120
    while not (metrics.exists() and len(metrics.read_text().splitlines()) > 3) and time.monotonic() < deadline:
        time.sleep(0.005)
    os.kill(os.getpid(), how)


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_ctrl_c_save_the_last_whole_generation_and_say_how_to_resume(tmp_path, how):
    out = tmp_path / "run"
    threading.Thread(target=signal_after_three_rows, args=(out, how), daemon=True).start()
    long_run = ["--budget", "8000", "--checkpoint-every", "1000", "--out", str(out)]  # stopped long before its end
    result = CliRunner().invoke(main, ["train", *RUN, *long_run])
    written, saved = len(rows(out)), RunFolder(out).load_checkpoint()["iteration"]
    assert result.exit_code == 1 and saved >= 2 and saved in (written - 1, written), result.output
    assert f"checkpoint (generation {saved}) kept" in result.output
    assert f"continue with: drrl train --resume {out}" in result.output
    setup, counters = prepare_resume(RunFolder(out))
    setup.close()
    assert counters.iteration == saved and len(rows(out)) == saved  # metrics past the checkpoint dropped


def test_resuming_a_finished_run_changes_nothing(uninterrupted):
    before = (uninterrupted / "metrics.csv").read_text()
    result = CliRunner().invoke(main, ["train", "--resume", str(uninterrupted)])
    assert result.exit_code == 0 and "is complete: all 16 generations done" in result.output
    assert (uninterrupted / "metrics.csv").read_text() == before


def test_resume_takes_the_run_s_own_settings(uninterrupted):
    result = CliRunner().invoke(main, ["train", "--resume", str(uninterrupted), "--budget", "400", "--seed", "1"])
    assert result.exit_code == 2 and "drop --budget, --seed" in result.output
