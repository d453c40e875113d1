"""The world model's memory beside the observation (drrl.models.remembering): the same [o_t, h_{t−1}] in reality
and in imagination, and a model-based run whose policy reads it."""

import json

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from gymnasium import spaces
from pydantic import ValidationError

from drrl.cli import main
from drrl.envs.batch import make_batch_env
from drrl.models import ImaginedEnv
from drrl.models.recurrent import WorldModel
from drrl.models.remembering import Remembering
from drrl.settings import ModelBasedSettings

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

ACTIONS = spaces.Box(-1.0, 1.0, (1,), np.float32)


def model(kind: str = "rnn", members: int = 1) -> WorldModel:
    torch.manual_seed(0)
    return WorldModel(4, 1, (8, 5), kind, members=members)


def memories_stepped_by_hand(world: WorldModel, observations: list[np.ndarray], actions: list[np.ndarray]) -> list:
    """h_{t−1} for every step t, from WorldModel.step on the observations and actions before it."""
    state, memories = world.initial_state(len(observations[0])), [np.zeros((len(observations[0]), 5))]
    for observation, action in zip(observations[:-1], actions, strict=True):
        _, state = world.step(torch.as_tensor(observation), torch.as_tensor(action), state)
        memories.append(world.memory(state)[0].detach().numpy())
    return memories


@pytest.mark.parametrize("kind", ["rnn", "lstm"])
def test_a_real_env_is_seen_with_the_memory_of_the_steps_before(kind):
    world = model(kind)
    env, twin = Remembering(make_batch_env("cartpole", 3), world), make_batch_env("cartpole", 3)
    seen, _ = env.reset(seed=7)
    observations = [twin.reset(seed=7)[0]]
    rows, actions = [seen], [np.full((3, 1), a, np.float32) for a in (0.5, -1.0, 0.2)]
    for action in actions:
        rows.append(env.step(action)[0])
        observations.append(twin.step(action)[0])
    assert env.single_observation_space.shape == (9,) and rows[0].shape == (3, 9)
    expected = memories_stepped_by_hand(world, observations, actions)
    for row, observation, memory in zip(rows, observations, expected, strict=True):
        np.testing.assert_allclose(row[:, :4], observation, rtol=1e-6)  # the env's own observation, untouched
        np.testing.assert_allclose(row[:, 4:], memory, atol=1e-6)
    assert np.abs(rows[-1][:, 4:]).min() > 0  # the memory moved from its zero start


def test_an_imagined_episode_is_seen_with_the_memory_it_runs_on():
    world, starts = model(), np.array([[0.1, 0.0, -0.05, 0.2]], np.float32)
    env = ImaginedEnv(world, starts, 2, ACTIONS, horizon=10, memory=True)
    seen = [env.reset(seed=3)[0]]
    actions = [np.array([[0.3], [-0.7]], np.float32), np.array([[1.0], [0.0]], np.float32)]
    for action in actions:
        seen.append(env.step(action)[0])
    observations = [rows[:, :4] for rows in seen]
    np.testing.assert_allclose(observations[0], np.repeat(starts, 2, axis=0))
    expected = memories_stepped_by_hand(world, observations, actions)
    for rows, memory in zip(seen, expected, strict=True):
        np.testing.assert_allclose(rows[:, 4:], memory, atol=1e-6)


def test_a_restarted_imagined_episode_forgets():
    env = ImaginedEnv(model(), np.zeros((1, 4), np.float32), 1, ACTIONS, horizon=1, memory=True)
    env.reset(seed=0)
    ended = env.step(np.ones((1, 1), np.float32))
    assert ended[3].all() and np.abs(ended[0][:, 4:]).max() > 0
    restarted = env.step(np.ones((1, 1), np.float32))[0]  # next-step autoreset: a new episode's first observation
    np.testing.assert_array_equal(restarted[:, 4:], 0.0)


def test_only_one_recurrent_model_has_a_memory_to_read():
    with pytest.raises(ValidationError, match="ensemble_size 1"):
        ModelBasedSettings(policy_memory=True, ensemble_size=3)
    for kind in ("linear", "mlp"):
        with pytest.raises(ValidationError, match="model_kind 'rnn' or 'lstm'"):
            ModelBasedSettings(policy_memory=True, model_kind=kind)
    with pytest.raises(ValueError, match="ensemble of 2"):
        Remembering(make_batch_env("cartpole", 1), model(members=2))


def test_a_model_based_run_whose_policy_reads_the_memory_trains_and_is_evaluated(tmp_path):
    out = tmp_path / "run"
    quick = {"hidden": [16], "unfold": 2, "overshoot": 6, "fit_updates": 30, "refit_updates": 30, "patience": 3}
    config = tmp_path / "memory.json"
    config.write_text(json.dumps({"model_based": quick, "popsize": 8, "episodes_per_candidate": 2, "eval_episodes": 5}))
    args = [
        "--config",
        str(config),
        "--model-based",
        "--policy-memory",
        "--budget",
        "4",
        "--generations-per-iteration",
        "3",
    ]
    trained = CliRunner().invoke(main, ["train", "cartpole-po", *args, "--quiet", "--out", str(out)])
    assert trained.exit_code == 0, trained.output
    saved = json.loads((out / "config.json").read_text())
    assert saved["world"]["policy_memory"] is True
    evaluated = CliRunner().invoke(main, ["eval", str(out), "--episodes", "3"])
    assert evaluated.exit_code == 0, evaluated.output
    assert "3 episodes: return" in evaluated.output
