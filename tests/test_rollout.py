import subprocess
import sys

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium import spaces

from drrl.envs.batch import ActionMap, make_batch_env
from drrl.policies import linear
from drrl.rollout import Evaluation, NonFiniteOutput, episode_seeds, evaluate


def one_at_a_time(policy, params, env_id, seeds, episodes):
    """Reference: each episode alone on a single env, summing its rewards until it ends."""
    env = gymnasium.make(env_id)
    action_map = ActionMap(env.action_space)
    returns, steps = np.zeros(len(seeds)), np.zeros(len(seeds), dtype=np.int64)
    for slot, seed in enumerate(seeds):
        weights = policy.unflatten(params[slot // episodes : slot // episodes + 1])
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            raw, _ = policy.act(weights, torch.as_tensor(obs, dtype=torch.float32).view(1, 1, -1), None)
            obs, reward, terminated, truncated, _ = env.step(action_map(raw.view(1, -1))[0])
            returns[slot] += reward
            steps[slot] += 1
            done = terminated or truncated
    return returns.reshape(len(params), episodes), steps.reshape(len(params), episodes)


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Pendulum-v1"])
def test_batched_rollout_equals_one_episode_at_a_time(env_id):
    population, episodes = 4, 3
    env = make_batch_env(env_id, population * episodes, "gymnasium")
    policy = linear(env.single_observation_space.shape[0], ActionMap(env.single_action_space).size)
    params = torch.randn(population, policy.num_params, generator=torch.Generator().manual_seed(1))
    result = evaluate(policy, params, env, episodes, seed=7)
    expected, steps = one_at_a_time(policy, params, env_id, episode_seeds(7, population, episodes), episodes)
    np.testing.assert_allclose(result.episode_returns.numpy(), expected, rtol=1e-6)
    np.testing.assert_array_equal(result.episode_steps.numpy(), steps)
    assert result.steps == steps.sum() and result.episodes == population * episodes
    torch.testing.assert_close(result.returns, result.episode_returns.mean(dim=1))
    shifted = (expected - 0.5 * steps).mean(axis=1)  # 0.5 taken from every step's reward
    np.testing.assert_allclose(result.returns_less(0.5).numpy(), shifted, rtol=1e-6)


def test_cartpole_episodes_that_fail_early_are_masked_and_counted_exactly():
    env = make_batch_env("CartPole-v1", 6)
    policy = linear(4, 2)
    params = torch.zeros(6, policy.num_params)
    params[:3, 0] = 1.0  # push by cart position: falls within a few dozen steps
    result = evaluate(policy, params, env, 1, seed=0)
    assert bool(result.terminated.all())
    # CartPole-v1 pays 1 per step, so a masked rollout's return is its length and the lengths add up to the steps.
    assert result.episode_returns.sum().item() == result.steps
    assert result.steps < 6 * 500


def test_common_starts_pair_candidates_on_the_same_episodes():
    seeds = episode_seeds(3, population=4, episodes=2)
    assert seeds[0::2] == [seeds[0]] * 4 and seeds[1::2] == [seeds[1]] * 4 and seeds[0] != seeds[1]


def test_env_size_must_match_the_population():
    env = make_batch_env("CartPole-v1", 5)
    with pytest.raises(ValueError, match="need 6"):
        evaluate(linear(4, 2), torch.zeros(3, 10), env, episodes=2)


def test_max_steps_cuts_long_episodes():
    env = make_batch_env("Pendulum-v1", 2)
    result = evaluate(linear(3, 1), torch.zeros(2, 4), env, 1, seed=0, max_steps=10)
    assert result.steps == 20 and not result.terminated.any()


def test_action_map_scales_bounded_boxes_and_picks_discrete_argmax():
    box = ActionMap(spaces.Box(-2.0, 2.0, (1,), np.float32))
    np.testing.assert_allclose(box(torch.tensor([[0.5], [5.0], [-3.0]])), [[1.0], [2.0], [-2.0]])
    shifted = ActionMap(spaces.Box(np.array([0, 10], np.float32), np.array([1, 20], np.float32)))
    np.testing.assert_allclose(shifted(torch.tensor([[0.0, -1.0]])), [[0.5, 10.0]])
    discrete = ActionMap(spaces.Discrete(3, start=-1))
    assert discrete.size == 3 and discrete(torch.tensor([[0.1, 0.9, 0.2], [2.0, 0.0, 0.0]])).tolist() == [0, -1]


def test_action_map_s_raw_outputs_map_back_onto_the_actions_they_came_from():
    for space, actions in (
        (spaces.Box(-2.0, 2.0, (1,), np.float32), [[1.0], [-2.0]]),
        (spaces.Box(np.array([0, 10], np.float32), np.array([1, 20], np.float32)), [[0.5, 10.0]]),
        (spaces.Box(-np.inf, np.inf, (2,), np.float32), [[7.0, -3.0]]),
        (spaces.Discrete(3, start=-1), [0, -1, 1]),
    ):
        action_map = ActionMap(space)
        raw = action_map.raw(actions)
        assert raw.dtype == np.float32 and raw.shape == (len(actions), action_map.size)
        np.testing.assert_allclose(action_map(torch.as_tensor(raw)), actions)


def test_unsupported_spaces_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="needs a 1-D Box"):
        make_batch_env("tests/WordObserving-v0", 2)
    with pytest.raises(ValueError, match="1-D Box or a Discrete"):
        ActionMap(spaces.MultiBinary(3))


def test_unknown_env_names_drrls_own_and_the_closest_ids():
    with pytest.raises(ValueError, match=r"unknown environment 'Nope-v9'; drrl's own: .*cartpole.*Pendulum-v1"):
        make_batch_env("Nope-v9", 2)
    with pytest.raises(ValueError, match=r"unknown environment 'Pendulm-v1'; did you mean Pendulum-v1"):
        make_batch_env("Pendulm-v1", 2)


class HugeRewardEnv(gymnasium.Env):
    """Pays 1e308 a step for 3 steps: every reward is finite, their sum is not."""

    observation_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(1, np.float32), 1e308, self.t == 3, False, {}


def test_a_return_that_overflows_stops_the_rollout():
    env = gymnasium.vector.SyncVectorEnv([HugeRewardEnv, HugeRewardEnv])
    with pytest.raises(NonFiniteOutput, match="non-finite return inf at step 3 of candidate 0's episode 0"):
        evaluate(linear(1, 1), torch.zeros(2, 2), env, episodes=1, seed=0)


ROLLOUT_LIKE_ALLOCATIONS = """
import resource, sys
import numpy as np
from drrl.rollout.memory import retain_freed_memory
if sys.argv[1] == "retain" and not retain_freed_memory():
    sys.exit(3)  # not glibc
def step():  # forty arrays of 160 KB made and dropped, like one step of 20,000 cart-poles
    return sum(np.ones(20_000)[0] for _ in [np.ones(20_000) for _ in range(40)])
step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def page_faults(mode):
    done = subprocess.run([sys.executable, "-c", ROLLOUT_LIKE_ALLOCATIONS, mode], capture_output=True, text=True)
    if done.returncode == 3:
        pytest.skip("the C library is not glibc")
    assert done.returncode == 0, done.stderr
    return int(done.stdout)


@pytest.mark.slow
def test_retained_memory_stops_rollout_steps_from_faulting_their_pages_in_again():
    assert page_faults("default") > 2000  # glibc gives the arrays back and faults them in again every step
    assert page_faults("retain") < 200


def test_an_env_whose_dependency_is_missing_is_refused_with_the_pip_extra(monkeypatch):
    for name in [name for name in sys.modules if name.startswith("gymnasium.envs.box2d")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "Box2D", None)  # as if gymnasium[box2d] were not installed
    with pytest.raises(ValueError, match=r'LunarLander-v3 cannot be made here: .*pip install "gymnasium\[box2d\]"'):
        make_batch_env("LunarLander-v3", 2, "gymnasium")


def test_close_matches_name_only_envs_that_can_be_made_here(monkeypatch):
    for name in [name for name in sys.modules if name.startswith("gymnasium.envs.box2d")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "Box2D", None)
    with pytest.raises(ValueError) as refused:
        make_batch_env("LunarLandr-v3", 2)
    assert "unknown environment 'LunarLandr-v3'" in str(refused.value) and "did you mean" not in str(refused.value)


def test_observation_moments_are_those_of_every_observation_acted_on_however_the_candidates_are_split():
    env = make_batch_env("CartPole-v1", 6, "gymnasium")
    policy = linear(4, 2)
    params = torch.randn(6, policy.num_params, generator=torch.Generator().manual_seed(2))
    seen = []

    class Watching(linear(4, 2).__class__):
        def act(self, weights, obs, state):
            seen.append(obs.reshape(-1, 4).clone())
            return super().act(weights, obs, state)

    watching = Watching(4, 2, (), activation="identity")
    whole = evaluate(watching, params, env, 1, seed=4, moments=True)
    acted = torch.stack(seen).double().view(len(seen), 6, 4)  # (step, slot): ended slots' too
    halves = [
        evaluate(policy, part, make_batch_env("CartPole-v1", 3, "gymnasium"), 1, seed=4, moments=True)
        for part in (params[:3], params[3:])
    ]
    joined = Evaluation.concat(halves).moments
    assert np.array_equal(joined.total, whole.moments.total) and np.array_equal(joined.count, whole.moments.count)
    assert whole.moments.count.sum() == whole.steps and len(acted) == max(whole.moments.count)
    mean, std = whole.moments.mean_std()
    expected = torch.cat([acted[: whole.moments.count[slot], slot] for slot in range(6)])  # a slot runs from step 0
    torch.testing.assert_close(mean.double(), expected.mean(0), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(std.double(), expected.std(0, unbiased=False), rtol=1e-4, atol=1e-6)
