"""Behaviour cloning (drrl.training.cloning): the demonstrator's actions are what is recorded, episodes and steps are
counted exactly, the fit finds a known linear demonstrator, and a run starts its search from the clone."""

import csv

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from pydantic import ValidationError

from drrl.cli import main
from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.stack_env import BaxterStackVectorEnv
from drrl.envs.registry import lookup
from drrl.policies import make_policy
from drrl.settings import TrainConfig, describe_errors
from drrl.streams import Stream, derive_seed
from drrl.training.cloning import Demonstrations, clone, cloned, demonstrated
from drrl.training.train import prepare

GAINS = np.array([0.3, 0.2, -1.5, -0.4], dtype=np.float32)  # a linear demonstrator on the thesis cart-pole


def linear_demonstrator(observations):  # its actions beyond [-1, 1] are clipped by the env, and noted as they are
    return (observations @ GAINS)[:, None]


def test_demonstrations_note_the_demonstrators_actions_and_count_every_step():
    acted = []

    def actor(observations):  # drives the env; its outputs must not be what is recorded
        acted.append(len(observations))
        return np.full((len(observations), 1), 0.5, dtype=np.float32)

    told = []
    record = demonstrated(
        linear_demonstrator, "cartpole", 5, seed=1, noise=0.0, actor=actor, stepped=lambda *now: told.append(now)
    )
    assert [steps for steps, _ in told] == list(range(1, len(told) + 1)) and told[-1][1] == 5  # a progress bar's
    ended = [ended for _, ended in told]
    assert ended == sorted(ended)
    np.testing.assert_allclose(record.raw_actions, linear_demonstrator(record.observations), atol=1e-6)
    assert record.episodes == 5 and record.steps == len(record.observations) and acted
    # a constant push ends every episode early, so there are fewer steps than 5 whole episodes
    assert 5 <= record.steps < 5 * 1000


@pytest.mark.parametrize("spec, bias", [("linear", 0.4), ("linear:nobias", 0.0)])
@pytest.mark.slow
def test_the_clone_of_a_linear_demonstrator_is_that_linear_policy(spec, bias):
    rng = np.random.default_rng(0)
    observations = rng.normal(size=(5000, 4)) * [0.1, 1.0, 3.0, 0.5] + (bias != 0) * np.array([2, -1, 0, 5])
    observations = observations.astype(np.float32)
    record = Demonstrations(observations, (observations @ GAINS + bias)[:, None], 10)
    policy = make_policy(spec, 4, 1)
    center = clone(policy, record, seed=0)  # reads raw observations: the standardisation is folded in
    np.testing.assert_allclose(center[:4].numpy(), GAINS, atol=2e-3)
    if bias:
        assert abs(float(center[4]) - bias) < 2e-2


@pytest.mark.slow
def test_rounds_spend_the_episodes_asked_for_and_later_rounds_are_driven_by_the_clone():
    policy = make_policy("linear:nobias", 4, 1)
    center, record = cloned(policy, linear_demonstrator, "cartpole", 6, rounds=3, seed=0, noise=0.1)
    assert record.episodes == 6 and record.steps == len(record.observations) == len(record.raw_actions)
    assert center.shape == (policy.num_params,)


def test_the_scripted_stacker_has_no_memory():
    env = BaxterStackVectorEnv(6, controller="end_point", positions="random")
    observations, _ = env.reset(seed=0)
    stacker = ScriptedStacker(env.task)
    for _ in range(300):
        actions = stacker.act(observations)
        observations, *_ = env.step(actions)
    env.close()
    reversed_rows = stacker.act(observations[::-1])[::-1]
    np.testing.assert_array_equal(stacker.act(observations), reversed_rows)  # each row from its own observation
    np.testing.assert_array_equal(stacker.act(observations[2:3]), stacker.act(observations)[2:3])


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"env": "cartpole"}, "has no scripted demonstrator"),
        ({"env": "baxter-stack-end-point", "policy": "lstm:8"}, "feed-forward policies"),
    ],
)
def test_a_run_that_cannot_clone_is_refused_before_any_work(settings, message):
    config = TrainConfig(**settings, demonstrations=4, budget=20, popsize=4)
    with pytest.raises(ValueError, match=message):
        prepare(config)


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"model_based": {}}, "demonstrations: a setting of model-free runs, not of model-based ones"),
        ({"observation_norm": True}, "reads raw observations"),
        ({"demonstration_rounds": 8}, "one episode a round"),
        ({"budget": 6}, "less 4 demonstrations is smaller than one generation"),
    ],
)
def test_bad_demonstration_settings_are_refused_in_one_line(settings, message):
    with pytest.raises(ValidationError) as error:
        TrainConfig(**{"env": "baxter-stack-end-point", "demonstrations": 4, "popsize": 4, "budget": 20, **settings})
    assert message in describe_errors(error.value)


@pytest.mark.slow
def test_a_run_from_demonstrations_counts_them_as_real_episodes_and_starts_from_the_clone(tmp_path):
    out, settings = tmp_path / "run", tmp_path / "short.toml"
    settings.write_text("max_steps = 30\n")
    args = ["train", "baxter-stack-end-point", "--policy", "mlp:8", "--demonstrations", "2", "--demonstration-rounds"]
    args += ["1", "--popsize", "2", "--budget", "4", "--config", str(settings), "--eval-episodes", "2", "--quiet"]
    result = CliRunner().invoke(main, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    with (out / "metrics.csv").open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert int(row["real_episodes"]) == 4 and int(row["real_steps"]) == 4 * 30  # 2 demonstrations, 2 candidates
    config = TrainConfig(env="baxter-stack-end-point", policy="mlp:8", demonstrations=2, demonstration_rounds=1)
    config = config.updated(popsize=2, budget=4, max_steps=30, eval_episodes=2)
    setup = prepare(config)
    try:
        assert setup.spent == (2, 60)
        entry = lookup("baxter-stack-end-point")
        seed = derive_seed(config.seed, 0, Stream.DEMONSTRATING)
        noise = config.world.start.noise
        expected, _ = cloned(setup.policy, entry.demonstrator, entry.env_id, 2, 1, seed, noise, max_steps=30)
        torch.testing.assert_close(setup.search.center, expected)
        assert not torch.equal(expected, setup.policy.initial_center())
    finally:
        setup.close()
