"""Restarts (``restart_every``): attempts of a model-free search, each from a new random centre, until one ends
with a centre that solves the task; the first attempt is the run without restarts (resuming across a restart:
test_loop.py)."""

import csv
from pathlib import Path

import pytest
from click.testing import CliRunner

from drrl.cli import main
from drrl.compare import curve_budget, method_config
from drrl.runs import RunFolder, learning_curve
from drrl.settings import TrainConfig
from drrl.training.train import train

CRITERIA = ("balanced", "near_optimal")  # the thesis cart-pole's verdict
SOLVING = TrainConfig(restart_every=40, budget=3000, seed=0)  # attempts 1-3 miss near_optimal, attempt 4 solves


def rows(out: Path) -> list[dict]:
    with (out / "metrics.csv").open(newline="") as handle:
        return [{key: value for key, value in row.items() if key != "wall_time"} for row in csv.DictReader(handle)]


@pytest.fixture(scope="module")
def solving(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("restarts") / "run"
    train(SOLVING, out)
    return out


@pytest.mark.slow
def test_the_run_ends_after_the_first_attempt_whose_last_centre_solves_the_task(solving):
    written = rows(solving)
    assert [int(row["attempt"]) for row in written] == [(g - 1) // 40 + 1 for g in range(1, len(written) + 1)]
    ends = [row for row in written if int(row["generation"]) % 40 == 0]
    assert written[-1] is ends[-1] and int(written[-1]["real_episodes"]) < SOLVING.budget
    assert all(ends[-1][name] == "1" for name in CRITERIA)
    assert not any(all(row[name] == "1" for name in CRITERIA) for row in written[:-40])  # earlier attempts missed


def test_the_learning_curve_marks_every_restart(solving):
    figure = learning_curve(RunFolder(solving).read_metrics(), "restarts")
    marks = [line for line in figure.axes[0].lines if line.get_linestyle() == ":"]
    assert [line.get_xdata()[0] for line in marks] == [320, 640, 960]  # after attempts 1-3, 8 episodes a generation


def test_each_attempt_starts_from_a_new_centre_and_the_first_is_the_run_without_restarts(solving, tmp_path):
    written = rows(solving)
    alone = train(SOLVING.updated(restart_every=None, budget=320), tmp_path / "alone")
    assert [{k: v for k, v in row.items() if k != "attempt"} for row in written[:40]] == rows(tmp_path / "alone")
    assert alone.generations == 40
    firsts = [float(row["sigma_norm"]) for row in written if int(row["generation"]) % 40 == 1]
    lasts = [float(row["sigma_norm"]) for row in written if int(row["generation"]) % 40 == 0]
    assert all(first > 2 * last for first, last in zip(firsts[1:], lasts, strict=False))  # σ starts again at σ₀
    starts = [float(row["mean_return"]) for row in written if int(row["generation"]) % 40 == 1]
    assert len(set(starts)) == len(starts)  # every attempt's first candidates differ


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["cartpole", "--restart-every", "5", "--model-based"],
            "restart_every: a setting of model-free runs, not of model-based",
        ),
        (["Humanoid-v5", "--restart-every", "5"], "restart_every: Humanoid-v5 has no verdict"),
        (["cartpole", "--restart-every", "0"], "restart_every"),
    ],
)
def test_restarts_are_refused_where_they_cannot_work_in_one_line(tmp_path, args, message):
    result = CliRunner().invoke(main, ["train", *args, "--out", str(tmp_path / "run")])
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run").exists()


def test_compare_follows_one_search_one_attempt_long_on_an_env_whose_runs_restart():
    assert TrainConfig(env="Pendulum-v1").world.restart_every == 100  # Pendulum-v1's own runs restart
    assert method_config("SyS-PGPE", 0, 51_200, {"env": "Pendulum-v1"}).world.restart_every is None
    assert curve_budget("Pendulum-v1", 300) == 100 * 64 * 8 and curve_budget("cartpole-swingup", 300) == 40_000


def test_the_progress_bar_names_the_attempt(tmp_path):
    result = CliRunner().invoke(
        main, ["train", "cartpole", "--restart-every", "2", "--budget", "32", "--out", str(tmp_path / "run")]
    )
    assert result.exit_code == 0 and "generation 4 (attempt 2) |" in result.output
