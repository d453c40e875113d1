"""The engines that batch an env: the same episodes as Gymnasium's, no step computed that is not counted, and the
engine a run used written to its config."""

import os
import signal

import gymnasium
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from drrl.cli import main
from drrl.envs import compiled, pool
from drrl.envs.batch import choose_engine, make_batch_env
from drrl.envs.cores import available_cores
from drrl.envs.processes import ProcessEpisodes
from drrl.envs.rendered import rendering_env
from drrl.policies import linear
from drrl.rollout import evaluate
from drrl.runs import RunFolder


class CountingSteps(gymnasium.Wrapper):
    def __init__(self, env, tally):
        super().__init__(env)
        self.tally = tally

    def step(self, action):
        self.tally[0] += 1
        return self.env.step(action)


def random_candidates(env, population, seed=1):
    policy = linear(env.single_observation_space.shape[0], 3 if env.single_action_space.shape == () else 1)
    return policy, torch.randn(population, policy.num_params, generator=torch.Generator().manual_seed(seed))


def swinging_candidates(population, seed=1):
    """Acrobot policies that push the way the second joint turns (pumping energy in), perturbed: episodes that end
    anywhere between about a hundred steps and the limit of 500."""
    policy = linear(6, 3)
    weights = torch.zeros(6, 3)
    weights[5, 0], weights[5, 2] = -1.0, 1.0  # torque -1 when θ̇2 < 0, +1 when θ̇2 > 0
    center = torch.cat([weights.flatten(), torch.zeros(3)])
    noise = torch.randn(population, policy.num_params, generator=torch.Generator().manual_seed(seed))
    return policy, center + 0.5 * noise


def test_the_gymnasium_engine_runs_gymnasiums_episodes_and_steps_no_ended_one():
    """Acrobot's episodes end anywhere from a few dozen steps to its limit of 500: Gymnasium's SyncVectorEnv steps
    every env to the longest; the gymnasium engine only the running ones, with the same returns."""
    env = make_batch_env("Acrobot-v1", 16, "gymnasium")
    tally = [0]
    env.envs = [CountingSteps(single, tally) for single in env.envs]
    policy, params = swinging_candidates(8)
    ours = evaluate(policy, params, env, 2, seed=3)
    theirs = evaluate(policy, params, gymnasium.make_vec("Acrobot-v1", 16, vectorization_mode="sync"), 2, seed=3)
    assert torch.equal(ours.episode_returns, theirs.episode_returns) and ours.steps == theirs.steps
    assert tally[0] == ours.steps
    assert ours.episode_returns.max() > -500 and ours.episode_returns.min() == -500  # uneven lengths indeed


@pytest.mark.slow
def test_the_processes_engine_runs_the_gymnasium_engines_episodes_on_every_worker():
    """Three workers over 10 slots (4, 3 and 3 of them, dealt out in turn), episodes of uneven length: returns and
    counted steps those of the one-process engine, whose episodes are Gymnasium's own."""
    serial = make_batch_env("Acrobot-v1", 10, "gymnasium")
    env = ProcessEpisodes("Acrobot-v1", 10, workers=3)
    try:
        policy, params = swinging_candidates(5)
        ours, theirs = evaluate(policy, params, env, 2, seed=3), evaluate(policy, params, serial, 2, seed=3)
        assert env.workers == 3
        assert torch.equal(ours.episode_returns, theirs.episode_returns) and ours.steps == theirs.steps
        assert ours.episode_returns.max() > -500 and ours.episode_returns.min() == -500
    finally:
        workers = list(env._processes)
        env.close()
    assert len(workers) == 3 and not any(process.is_alive() for process in workers)


@pytest.mark.slow
def test_the_processes_engine_refuses_bad_options_at_once_leaves_ctrl_c_to_training_and_reports_failures():
    with pytest.raises(ValueError, match="cannot be made with options"):
        make_batch_env("Acrobot-v1", 2, "processes", {"no_such_option": 1})
    env = make_batch_env("CartPole-v1", 2, "processes")
    try:
        assert isinstance(env, ProcessEpisodes) and env.workers == min(2, available_cores())
        env.reset(seed=0)
        for worker in env._processes:  # Ctrl-C is the training process's to handle
            os.kill(worker.pid, signal.SIGINT)
        assert env.step(np.array([0, 1]))[1].tolist() == [1.0, 1.0]
        with pytest.raises(RuntimeError, match="an env worker failed: AssertionError"):
            env.step(np.array([0, 7]))  # CartPole's actions are 0 and 1
    finally:
        env.close()


def test_an_ended_episode_stays_where_it_ended_until_the_next_reset():
    env = make_batch_env("CartPole-v1", 2, "gymnasium")
    env.reset(seed=0)
    push_left = np.zeros(2, dtype=np.int64)
    terminated = np.zeros(2, dtype=bool)
    while not terminated.any():
        observations, rewards, terminated, _truncated, _ = env.step(push_left)
    ended = int(np.flatnonzero(terminated)[0])
    again, rewards, still_terminated, _, _ = env.step(push_left)
    assert np.array_equal(again[ended], observations[ended]) and rewards[ended] == 0 and still_terminated[ended]
    assert rewards[1 - ended] == 1 or still_terminated[1 - ended]  # the other one went on, unless it ended too
    restarted, _ = env.reset(seed=0)
    assert np.abs(restarted).max() <= 0.05


def test_discrete_and_tuple_observations_are_seen_one_hot_and_an_env_without_a_time_limit_is_cut(tmp_path):
    """FrozenLake observes its cell as Discrete(16), Blackjack a tuple of three: both flattened by Gymnasium's own
    rule, also where EnvPool ships the id (its toy-text tasks observe raw integers, so they stay on this engine).
    CliffWalking has no time limit: a run's episodes are cut at 1,000 steps by default, so a policy that never
    reaches the goal cannot stall it."""
    lake = make_batch_env("FrozenLake-v1", 3)
    assert lake.single_observation_space.shape == (16,)
    observations, _ = lake.reset(seed=[0, 1, 2])
    cells = [gymnasium.make("FrozenLake-v1").reset(seed=seed)[0] for seed in (0, 1, 2)]
    assert np.array_equal(observations, np.eye(16)[cells])
    assert rendering_env("FrozenLake-v1").observation_space.shape == (16,)  # drrl render sees what training saw
    blackjack = make_batch_env("Blackjack-v1", 2)
    assert blackjack.single_observation_space.shape == (32 + 11 + 2,)
    assert blackjack.reset(seed=[4, 5])[0].sum(axis=1).tolist() == [3, 3]  # one hot per part
    out = tmp_path / "cliff"
    arguments = ["train", "CliffWalking-v1", "--budget", "4", "--popsize", "4", "--eval-episodes", "1", "--quiet"]
    result = CliRunner().invoke(main, [*arguments, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert RunFolder(out).read_config().max_steps == 1000
    assert RunFolder(out).read_config().engine == "gymnasium"
    assert int((out / "metrics.csv").read_text().splitlines()[-1].split(",")[2]) <= 4 * 1000


def test_auto_picks_drrls_own_batch_for_its_envs_and_refuses_engines_that_cannot_run_an_id(monkeypatch):
    assert choose_engine("cartpole") == "native"
    monkeypatch.setattr(pool, "installed", lambda: False)
    monkeypatch.setattr(compiled, "installed", lambda: False)
    assert choose_engine("Acrobot-v1") == "gymnasium"
    with pytest.raises(ValueError, match=r'engine numba is not installed; pip install "drrl\[numba\]"'):
        choose_engine("Acrobot-v1", "numba")
    with pytest.raises(ValueError, match=r'engine envpool is not installed; pip install "drrl\[envpool\]"'):
        choose_engine("Acrobot-v1", "envpool")
    with pytest.raises(
        ValueError, match="Acrobot-v1 has no native drrl batch; its engines are numba, envpool, gymnasium and processes"
    ):
        choose_engine("Acrobot-v1", "native")


@pytest.mark.slow
def test_a_run_names_the_engine_it_used_in_its_config(tmp_path, monkeypatch):
    monkeypatch.setattr(pool, "installed", lambda: False)
    monkeypatch.setattr(compiled, "installed", lambda: False)
    out = tmp_path / "run"
    result = CliRunner().invoke(
        main,
        [
            "train",
            "Acrobot-v1",
            "--budget",
            "4",
            "--popsize",
            "4",
            "--eval-episodes",
            "2",
            "--quiet",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    assert RunFolder(out).read_config().engine == "gymnasium"
    spread = tmp_path / "spread"
    arguments = ["train", "Acrobot-v1", "--budget", "4", "--popsize", "4", "--eval-episodes", "2", "--quiet"]
    result = CliRunner().invoke(main, [*arguments, "--engine", "processes", "--out", str(spread)])
    assert result.exit_code == 0, result.output
    assert RunFolder(spread).read_config().engine == "processes"
    same_run = [
        [line.rsplit(",", 1)[0] for line in (run / "metrics.csv").read_text().splitlines()] for run in (out, spread)
    ]
    assert same_run[0] == same_run[1] and same_run[0][0].endswith("eval_episodes")  # all but the wall time
    if compiled.installed():  # Gymnasium's own episodes, compiled: the same run
        fast = tmp_path / "fast"
        result = CliRunner().invoke(main, [*arguments, "--engine", "numba", "--out", str(fast)])
        assert result.exit_code == 0, result.output
        assert RunFolder(fast).read_config().engine == "numba"
        assert [line.rsplit(",", 1)[0] for line in (fast / "metrics.csv").read_text().splitlines()] == same_run[0]
    refused = CliRunner().invoke(main, ["train", "cartpole", "--engine", "envpool", "--out", str(tmp_path / "x")])
    assert refused.exit_code == 2 and 'engine envpool is not installed; pip install "drrl[envpool]"' in refused.output


@pytest.mark.skipif(not pool.installed(), reason='needs EnvPool (pip install "drrl[envpool]")')
class TestEnvPool:
    def test_auto_picks_envpool_for_the_tasks_it_ships_beyond_numbas(self):
        assert choose_engine("Hopper-v5") == "envpool" and choose_engine("drrl/CartPole-v0") == "native"
        with pytest.raises(ValueError, match="EnvPool has no drrl/CartPole-v0; use engine gymnasium"):
            choose_engine("cartpole", "envpool")

    def test_episodes_are_a_pure_function_of_the_seed_and_pair_candidates_on_common_starts(self):
        env = make_batch_env("Acrobot-v1", 12, "envpool")
        policy, params = swinging_candidates(4)
        first, again = (evaluate(policy, params, env, 3, seed=5) for _ in range(2))
        assert torch.equal(first.episode_returns, again.episode_returns) and first.steps == again.steps
        same = params[:1].repeat(4, 1)
        paired = evaluate(policy, same, env, 3, seed=5).episode_returns
        assert (paired == paired[0]).all() and len(set(paired[0].tolist())) > 1

    def test_episodes_are_counted_exactly(self):
        env = make_batch_env("CartPole-v1", 6, "envpool")
        policy, params = random_candidates(env, 6)
        result = evaluate(policy, params, env, 1, seed=0)
        assert result.episode_returns.sum().item() == result.steps  # 1 a step until each episode ends
        assert 6 * 8 < result.steps < 6 * 500
