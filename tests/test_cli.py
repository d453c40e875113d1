import csv
import itertools
import subprocess
import sys
from pathlib import Path

import click
import gymnasium
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from drrl.cli import main
from drrl.cli.commands import advice_after_a_miss
from drrl.envs.gymnasium_tasks import alive_bonus_note
from drrl.envs.registry import lookup
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.settings.flat import flattened
from drrl.settings.presets import PRESETS, TASKS
from drrl.training.train import prepare

SMALL = ["--budget", "40", "--popsize", "10", "--eval-episodes", "5", "--eval-share", "1", "--quiet"]


def train(tmp_path, *args, name="run"):
    out = tmp_path / name
    result = CliRunner().invoke(main, ["train", *args, "--out", str(out)])
    return result, out


def metrics(out: Path) -> list[dict[str, str]]:
    with (out / "metrics.csv").open() as handle:
        return list(csv.DictReader(handle))


def test_train_writes_a_readable_run_folder_and_counts_real_episodes(tmp_path):
    result, out = train(tmp_path, "cartpole", *SMALL)
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} == {
        "config.json",
        "metrics.csv",
        "checkpoint.safetensors",
        "learning_curve.png",
    }
    rows = metrics(out)
    assert [int(r["real_episodes"]) for r in rows] == [10, 20, 30, 40]
    assert [int(r["eval_episodes"]) for r in rows] == [5, 10, 15, 20]  # measuring is counted apart
    steps = [int(r["real_steps"]) for r in rows]
    assert all(10 <= b - a <= 10 * 200 for a, b in itertools.pairwise([0, *steps]))
    assert "done: 4 generations, 40 real episodes" in result.output


def test_same_seed_gives_identical_metrics(tmp_path):
    first, second = (train(tmp_path, "cartpole", *SMALL, "--seed", "3", name=name)[1] for name in ("a", "b"))
    drop_time = lambda rows: [{k: v for k, v in row.items() if k != "wall_time"} for row in rows]  # noqa: E731
    assert drop_time(metrics(first)) == drop_time(metrics(second))
    other = train(tmp_path, "cartpole", *SMALL, "--seed", "4", name="c")[1]
    assert drop_time(metrics(other)) != drop_time(metrics(first))


def test_checkpoint_restores_the_search_exactly(tmp_path):
    _, out = train(tmp_path, "cartpole", *SMALL)
    folder = RunFolder(out)
    checkpoint = folder.load_checkpoint()
    search = prepare(folder.read_config()).search
    search.load_state_dict(checkpoint["search"])
    assert torch.equal(search.center, checkpoint["center"])
    assert checkpoint["real_episodes"] == 40 and checkpoint["iteration"] == 4
    # the best centre met the most verdict criteria (balanced, near-optimal) and, among those, returned most
    best = max(
        metrics(out), key=lambda row: (int(row["balanced"]) + int(row["near_optimal"]), float(row["center_return"]))
    )
    assert checkpoint["best_iteration"] == int(best["generation"])
    assert checkpoint["best_center_return"] == float(best["center_return"])


def test_measuring_every_few_generations_keeps_the_columns_and_prefers_a_balanced_centre(tmp_path):
    result, out = train(
        tmp_path,
        "cartpole",
        "--budget",
        "160",
        "--popsize",
        "8",
        "--eval-episodes",
        "5",
        "--eval-every",
        "3",
        "--quiet",
    )
    assert result.exit_code == 0, result.output
    rows = metrics(out)
    assert (out / "learning_curve.png").is_file() and len(rows) == 20
    measured = [row for row in rows if int(row["generation"]) % 3 == 0 or row["generation"] == "20"]
    assert all(row["balanced"] in ("0", "1") for row in measured)
    assert all(row["balanced"] == "nan" for row in rows if row not in measured)
    balanced = [row for row in measured if row["balanced"] == "1"]
    assert balanced, "the defaults balance the cart-pole within 160 episodes"
    best = max(balanced, key=lambda row: (int(row["near_optimal"]), float(row["center_return"])))
    checkpoint = RunFolder(out).load_checkpoint()
    assert checkpoint["best_iteration"] == int(best["generation"]) and checkpoint["best_center_criteria"] >= 1


def test_eval_reports_the_cartpole_verdicts(tmp_path):
    _, out = train(tmp_path, "cartpole", *SMALL)
    result = CliRunner().invoke(main, ["eval", str(out), "--episodes", "7"])
    assert result.exit_code == 0, result.output
    assert "best measured centre (generation" in result.output and "7 episodes: return" in result.output
    assert "balanced:" in result.output and "near-optimal:" in result.output
    final = CliRunner().invoke(main, ["eval", str(out), "--episodes", "7", "--final"])
    assert "final centre (generation 4)" in final.output


def test_any_gymnasium_env_trains_and_evaluates(tmp_path):
    result, out = train(
        tmp_path,
        "--env",
        "Pendulum-v1",
        "--search",
        "pgpe",
        "--policy",
        "mlp:4",
        "--budget",
        "8",
        "--popsize",
        "4",
        "--episodes-per-candidate",
        "1",
        "--eval-episodes",
        "2",
        "--quiet",
    )
    assert result.exit_code == 0, result.output
    assert int(metrics(out)[-1]["real_steps"]) == 8 * 200
    assert (
        "the centre met none of Pendulum-v1's criteria (solved); settings that suit it: --search cmaes --policy "
        "mlp:16 --popsize 64 --episodes-per-candidate 8 --budget 409600; or model-based, with settings measured on it: "
        "drrl train Pendulum-v1 --model-based"  # its own defaults where the run set others, and its model-based ones
    ) in result.output
    evaluation = CliRunner().invoke(main, ["eval", str(out), "--episodes", "2"])
    assert "±" in evaluation.output and "balanced" not in evaluation.output
    assert "(Pendulum-v1 counts as solved at a mean return ≥ -200, drrl's level:" in evaluation.output


@pytest.mark.slow
def test_a_model_based_run_that_misses_is_told_the_env_s_own_model_based_settings(tmp_path):
    result, _ = train(
        tmp_path, "Pendulum-v1", "--model-based", "--budget", "2", "--generations-per-iteration", "1", "--quiet"
    )
    assert result.exit_code == 0, result.output
    assert "the centre met none of Pendulum-v1's criteria (solved); settings that suit it: --budget 30" in result.output
    assert "--model-based" not in result.output.split("settings that suit it")[1]


def test_a_run_with_the_env_s_own_settings_is_told_what_helps_a_run_of_its_kind():
    advice = {}
    for kind, model_based in (("model-free", None), ("model-based", {})):
        setup = prepare(TrainConfig(env="cartpole", model_based=model_based, eval_episodes=2))
        try:
            advice[kind] = advice_after_a_miss(setup)
        finally:
            setup.close()
    assert "--episodes-per-candidate" in advice["model-free"] and "--generations-per" not in advice["model-free"]
    assert "--generations-per" in advice["model-based"] and "--episodes-per-candidate" not in advice["model-based"]
    assert "mlp:32" in advice["model-free"]


@pytest.mark.parametrize(
    ("env", "settings", "not_again"),
    [
        ("cartpole", {"policy": "mlp:32"}, "mlp:32"),  # the generic advice, less the policy the run had
        ("cartpole-po", {"policy": "rnn:4", "popsize": 16}, "--policy rnn:4"),  # the task's own, which it had
    ],
)
def test_advice_after_a_miss_never_repeats_a_setting_the_run_had(env, settings, not_again):
    setup = prepare(TrainConfig(env=env, eval_episodes=2, **settings))
    try:
        advice = advice_after_a_miss(setup)
    finally:
        setup.close()
    assert not_again not in advice and advice.startswith(("try", "settings that suit it"))


def test_eval_gives_a_verdict_on_any_gymnasium_env_and_calls_out_a_farmed_alive_bonus(tmp_path):
    for env_id, level in (("Walker2d-v5", "≥ 3000, drrl's level: below the PPO"), ("Pusher-v5", "≥ -30, drrl's")):
        explained = lookup(env_id).explain
        assert explained is not None and level in explained(torch.zeros(1, 2), torch.zeros(1, 2, dtype=torch.bool))
    standing = alive_bonus_note("Walker2d-v5", torch.full((1, 4), 1056.0), torch.full((1, 4), 1000))
    assert standing is not None and standing.startswith("1000 of the mean return 1056.0 is the alive bonus")
    assert alive_bonus_note("Walker2d-v5", torch.full((1, 4), 3100.0), torch.full((1, 4), 1000)) is None
    assert alive_bonus_note("Pendulum-v1", torch.full((1, 4), -100.0), torch.full((1, 4), 200)) is None
    result, out = train(tmp_path, "Blackjack-v1", *SMALL)  # no reward_threshold, and no level of drrl's
    assert result.exit_code == 0, result.output
    evaluated = CliRunner().invoke(main, ["eval", str(out), "--episodes", "4"])
    assert evaluated.exit_code == 0 and "verdict:      none (it has no reward_threshold" in evaluated.output


def test_the_settings_measured_for_gymnasiums_tasks_are_their_defaults_and_valid():
    for env_id, presets in TASKS.items():
        if not env_id.startswith("drrl/"):
            config = flattened(TrainConfig(env=env_id))
            assert all(config[name] == value for name, value in PRESETS[presets["model-free"]].items())


def test_a_gymnasium_task_with_a_reward_threshold_is_judged_solved_or_not_by_it(tmp_path):
    result, out = train(
        tmp_path,
        "Acrobot-v1",
        "--engine",
        "gymnasium",
        "--budget",
        "4",
        "--popsize",
        "4",
        "--eval-episodes",
        "2",
        "--quiet",
    )
    assert result.exit_code == 0, result.output
    assert "solved" in metrics(out)[-1]
    assert "the centre met none of Acrobot-v1's criteria (solved); try a larger --budget" in result.output
    evaluation = CliRunner().invoke(main, ["eval", str(out), "--episodes", "2"])
    assert "solved:       no" in evaluation.output
    assert "(Acrobot-v1 counts as solved at a mean return ≥ -100, Gymnasium's reward_threshold)" in evaluation.output


def test_config_file_is_read_and_overridden_by_options(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('budget = 20\npopsize = 10\neval_episodes = 3\nsampler = "single"\n')
    result, out = train(tmp_path, "--config", str(config), "--sampler", "symmetric", "--quiet")
    assert result.exit_code == 0, result.output
    saved = RunFolder(out).read_config()
    assert (saved.budget, saved.search.sampler, saved.measuring.eval_episodes) == (20, "symmetric", 3)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--env", "NoSuchEnv-v3"], "unknown environment 'NoSuchEnv-v3'"),
        (["--policy", "cnn:3"], "accepted forms: linear, linear:nobias"),
        (["--sampler", "genetic"], "'genetic' is not one of"),
        (["--optimizer", "lbfgs"], "'lbfgs' is not one of"),
        (["--sigma-init", "0"], "sigma_init: Input should be greater than 0"),
        (["--popsize", "7"], "symmetric sampling needs an even popsize"),
        (["--budget", "5"], "smaller than one generation"),
        (["--env", "tests/WordObserving-v0"], "needs a 1-D Box"),
        (["cartpole", "--env", "Pendulum-v1"], "two environments given"),
    ],
)
def test_bad_input_is_refused_before_any_work(tmp_path, args, message):
    result, out = train(tmp_path, *args, "--quiet")
    assert result.exit_code == 2 and message in result.output, result.output
    assert not out.exists()


class NaNRewardEnv(gymnasium.Env):
    """Returns a NaN reward whenever the action is positive."""

    observation_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.ones(2, np.float32), {}

    def step(self, action):
        return np.ones(2, np.float32), float("nan") if action[0] > 0 else 0.0, True, False, {}


def test_non_finite_returns_stop_the_run_name_the_candidate_and_keep_the_folder(tmp_path):
    gymnasium.register("drrl-test/NaNReward-v0", entry_point=NaNRewardEnv)
    result, out = train(
        tmp_path,
        "--env",
        "drrl-test/NaNReward-v0",
        "--budget",
        "8",
        "--popsize",
        "4",
        "--policy",
        "linear:nobias",
        "--sigma-init",
        "1",
        "--eval-episodes",
        "1",
        "--quiet",
    )
    assert result.exit_code == 1
    assert "generation 1: " in result.output and "candidate 0" in result.output
    assert "run folder and checkpoint (generation 0) kept" in result.output
    assert RunFolder(out).load_checkpoint()["iteration"] == 0
    assert "NonFiniteOutput" in (out / "error.log").read_text()  # the run folder keeps the traceback


def test_debug_shows_the_traceback_behind_a_refusal(tmp_path):
    quiet = CliRunner().invoke(main, ["train", "--env", "Nope-v9", "--out", str(tmp_path / "a")])
    loud = CliRunner().invoke(main, ["--debug", "train", "--env", "Nope-v9", "--out", str(tmp_path / "b")])
    assert quiet.exit_code == loud.exit_code == 2
    assert "Traceback" not in quiet.output and "unknown environment 'Nope-v9'" in quiet.output
    assert "Traceback" in loud.output and "lookup" in loud.output


def test_an_occupied_out_is_refused_before_any_work_and_a_refused_run_leaves_no_folder(tmp_path, monkeypatch):
    """Preparing a run can be long work (recording demonstrations): an occupied --out is refused before it; a run
    refused while preparing leaves no folder it made behind, and an empty folder the user made stays."""
    occupied, made, users = tmp_path / "occupied", tmp_path / "made", tmp_path / "users"
    occupied.mkdir()
    (occupied / "notes.txt").write_text("mine")
    users.mkdir()
    with monkeypatch.context() as patched:
        patched.setattr(
            "drrl.cli.commands.prepare", lambda *args, **kwargs: pytest.fail("prepared before checking --out")
        )
        result = CliRunner().invoke(main, ["train", "cartpole", "--out", str(occupied)])
    assert result.exit_code == 2 and "already holds files; choose another --out" in result.output
    assert (occupied / "notes.txt").read_text() == "mine"
    for out in (made, users):
        refused = CliRunner().invoke(main, ["train", "--env", "Nope-v9", "--out", str(out)])
        assert refused.exit_code == 2 and "unknown environment 'Nope-v9'" in refused.output
    assert not made.exists() and users.is_dir()


def test_a_run_told_to_stop_when_solved_spends_no_real_episode_past_its_solved_centre(tmp_path):
    result, out = train(tmp_path, "cartpole", "--budget", "3000", "--eval-share", "1", "--stop-when-solved")
    rows = metrics(out)
    criteria = ("balanced", "near_optimal")
    assert result.exit_code == 0, result.output
    assert "the run stopped there (stop_when_solved)" in result.output
    assert "the best measured centre was balanced and near-optimal on its" in result.output
    assert all(rows[-1][name] == "1" for name in criteria)
    assert not any(all(row[name] == "1" for name in criteria) for row in rows[:-1])
    assert int(rows[-1]["real_episodes"]) < 3000
    resumed = CliRunner().invoke(main, ["train", "--resume", str(out)])
    assert resumed.exit_code == 0 and metrics(out) == rows  # solved: nothing more to do
    refused, _ = train(tmp_path, "Humanoid-v5", "--stop-when-solved", name="humanoid")
    assert refused.exit_code == 2 and "stop_when_solved: Humanoid-v5 has no verdict" in refused.output


@pytest.mark.slow
def test_a_run_told_to_stop_after_solved_measurements_in_a_row_stops_at_the_first_such_streak(tmp_path):
    first, _ = train(tmp_path, "cartpole", "--budget", "3000", "--eval-share", "1", "--stop-when-solved")
    result, out = train(
        tmp_path,
        "cartpole",
        "--budget",
        "3000",
        "--eval-share",
        "1",
        "--stop-when-solved",
        "--solved-in-a-row",
        "3",
        name="streak",
    )
    assert first.exit_code == 0 and result.exit_code == 0, result.output
    assert "the run stopped there (stop_when_solved)" in result.output
    solved = [all(row[name] == "1" for name in ("balanced", "near_optimal")) for row in metrics(out)]
    assert all(solved[-3:])
    assert not any(all(solved[i : i + 3]) for i in range(len(solved) - 3))
    assert len(solved) > len(metrics(tmp_path / "run"))  # went on past its first solved centre


def test_the_drrl_command_is_installed():
    drrl = Path(sys.executable).with_name("drrl")
    result = subprocess.run([drrl, "train", "--help"], capture_output=True, text=True, check=True)
    assert "--budget" in result.stdout and "--sampler" in result.stdout


def test_eval_explains_each_tasks_own_verdict(tmp_path):
    result, out = train(
        tmp_path,
        "cartpole-swingup",
        "--model-free",
        "--budget",
        "16",
        "--popsize",
        "8",
        "--eval-episodes",
        "4",
        "--quiet",
    )
    assert result.exit_code == 0, result.output
    evaluated = CliRunner().invoke(main, ["eval", str(out), "--episodes", "4"])
    assert evaluated.exit_code == 0, evaluated.output
    assert "solved:" in evaluated.output and "returned ≥ 160 of at most 250" in evaluated.output
    assert "200 steps" not in evaluated.output and "near-optimal" not in evaluated.output


def test_a_run_that_meets_no_criterion_is_told_the_settings_that_suit_its_task(tmp_path):
    result, _out = train(tmp_path, "cartpole-po", "--policy", "linear", "--budget", "16", "--eval-episodes", "4")
    assert result.exit_code == 0, result.output
    assert "settings that suit it: --policy rnn:4" in result.output


@pytest.mark.slow
def test_cmaes_and_model_based_on_ray_run_from_the_command_line(tmp_path):
    result, out = train(tmp_path, "cartpole", "--search", "sep-cmaes", *SMALL, name="cmaes")
    assert result.exit_code == 0, result.output
    assert RunFolder(out).load_checkpoint()["search"]["kind"] == "cmaes"
    pytest.importorskip("ray")
    result, out = train(
        tmp_path,
        "cartpole",
        "--model-based",
        "--budget",
        "4",
        "--generations-per-iteration",
        "2",
        "--model-hidden",
        "8",
        "--eval-episodes",
        "4",
        "--backend",
        "ray",
        "--workers",
        "1",
        "--quiet",
        name="ray",
    )
    assert result.exit_code == 0, result.output
    assert "done: 2 iterations, 4 real episodes" in result.output


@pytest.mark.slow
def test_a_run_folder_belongs_to_one_process_and_a_killed_ones_folder_is_taken_over(tmp_path):
    out = tmp_path / "run"
    drrl = str(Path(sys.executable).with_name("drrl"))
    process = subprocess.Popen(
        [drrl, "train", "cartpole", "--budget", "100000", "--quiet", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        while not (out / "metrics.csv").exists():
            assert process.poll() is None
        second, _ = train(tmp_path, "cartpole", *SMALL, name="other")
        assert second.exit_code == 0  # its own folder: fine
        same = CliRunner().invoke(main, ["train", "cartpole", *SMALL, "--out", str(out)])
        resumed = CliRunner().invoke(main, ["train", "--resume", str(out)])
        for result in (same, resumed):
            assert result.exit_code != 0 and "in use by another drrl process" in result.output
            assert "Traceback" not in result.output
    finally:
        process.kill()
        process.wait()
    RunFolder(out).claim().release()  # the killed process's hold went with it


def test_a_full_disk_stops_the_run_in_one_line_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    saves = []
    original = RunFolder.save_checkpoint

    def save_until_full(folder, state):
        saves.append(state["iteration"])
        if state["iteration"] >= 2:
            raise OSError(28, "No space left on device", str(folder.path / "checkpoint.safetensors.tmp"))
        original(folder, state)

    monkeypatch.setattr(RunFolder, "save_checkpoint", save_until_full)
    result, out = train(tmp_path, "cartpole", *SMALL, "--checkpoint-every", "2")
    assert result.exit_code == 1 and "No space left on device" in result.output, result.output
    assert "Traceback" not in result.output and "drrl train --resume" in result.output
    monkeypatch.setattr(RunFolder, "save_checkpoint", original)
    assert RunFolder(out).load_checkpoint()["iteration"] == 0  # the checkpoint written before the disk filled


def test_a_nan_environment_stops_a_model_based_run_in_one_message(tmp_path):
    if "drrl-test/NaNRewardLimited-v0" not in gymnasium.registry:
        gymnasium.register("drrl-test/NaNRewardLimited-v0", entry_point=NaNRewardEnv, max_episode_steps=5)
    result, _out = train(
        tmp_path,
        "--env",
        "drrl-test/NaNRewardLimited-v0",
        "--model-based",
        "--budget",
        "4",
        "--eval-episodes",
        "2",
        "--quiet",
    )
    assert result.exit_code == 1 and "non-finite reward" in result.output, result.output
    assert "Traceback" not in result.output and "run folder and checkpoint (iteration 0) kept" in result.output


@pytest.mark.parametrize("command", [[], *([name] for name in main.commands)])
def test_every_command_s_help_describes_each_option_in_plain_words(command):
    helped = CliRunner().invoke(main, [*command, "--help"], terminal_width=200)
    assert helped.exit_code == 0, helped.output
    for token in ("{", "None]", "BOOLEAN", "``"):  # a Python repr, an unset default, a value for on/off, RST
        assert token not in helped.output, f"drrl {' '.join(command)} --help shows {token!r}"
    group = main.commands[command[0]] if command else main
    for option in group.params:
        if isinstance(option, click.Option):
            assert option.help, f"drrl {' '.join(command)} {option.opts[0]} has no description"
            assert option.is_flag or option.type is not click.BOOL, f"{option.opts[0]} takes true/false: a flag"
