"""The numba engine (drrl.envs.compiled) against Gymnasium's own envs: the same episodes, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from drrl.envs import compiled
from drrl.envs.batch import choose_engine, make_batch_env

pytestmark = pytest.mark.skipif(not compiled.installed(), reason='needs numba: pip install "drrl[numba]"')


# actions that pump energy into the tasks that need it to end: a torque along the second link's velocity swings
# the acrobot's tip up, a push along the car's velocity takes it up the hill
PUMPING = {"Acrobot-v1": 5, "MountainCar-v0": 1, "MountainCarContinuous-v0": 1}  # the observation entry to push along


def some_actions(env_id: str, space, observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random actions, out-of-range ones among them for a Box; mostly pumping ones where the task needs them."""
    count = len(observations)
    if space.shape == ():
        actions = rng.integers(space.n, size=count)
        along = np.where(observations[:, PUMPING.get(env_id, 0)] > 0, 2, 0)
    else:
        actions = rng.uniform(-1.5 * space.high, 1.5 * space.high, (count, *space.shape)).astype(np.float32)
        along = np.abs(actions) * np.where(observations[:, PUMPING.get(env_id, 0)] > 0, 1, -1)[:, None]
    if env_id in PUMPING:
        pumping = rng.random(count) < 0.8
        actions[pumping] = along[pumping]
    return actions


@pytest.mark.parametrize("env_id", sorted(compiled.TASKS))
@pytest.mark.slow
def test_same_episodes_as_gymnasium(env_id):
    """Every observation, reward and end flag equals the gymnasium engine's (Gymnasium's env a slot, stepped in
    turn), from the same seeds and actions, including out-of-range Box actions and slots idle after their end."""
    fast, slow = make_batch_env(env_id, 8, "numba"), make_batch_env(env_id, 8, "gymnasium")
    ended = 0
    for seed in range(3):
        seeds = np.random.default_rng(seed).integers(2**63, size=8).tolist()
        observations, _ = fast.reset(seed=seeds)
        np.testing.assert_array_equal(observations, slow.reset(seed=seeds)[0])
        rng = np.random.default_rng(seed)
        for _ in range(600):
            actions = some_actions(env_id, fast.single_action_space, observations, rng)
            got, want = fast.step(actions), slow.step(actions)
            for a, b in zip(got[:4], want[:4], strict=True):
                np.testing.assert_array_equal(a, b)
            observations = got[0]
            if (got[2] | got[3]).all():
                break
        ended += int(got[2].sum())
        assert (got[2] | got[3]).all(), "every episode reaches its end or the time limit"
    if env_id != "Pendulum-v1":  # the pendulum never terminates, it is only cut at 200 steps
        assert ended > 0, "some episodes terminate, so the end condition is compared too"


def test_unseeded_resets_differ_and_go_on():
    env = make_batch_env("CartPole-v1", 4, "numba")
    first, _ = env.reset()
    second, _ = env.reset()
    assert len({row.tobytes() for row in np.concatenate([first, second])}) == 8


def test_auto_picks_it_and_refuses_options():
    assert choose_engine("Acrobot-v1") == "numba"
    assert choose_engine("Acrobot-v1", with_options=True) != "numba"
    with pytest.raises(ValueError, match="without options"):
        make_batch_env("Acrobot-v1", 2, "numba", {"render_mode": "rgb_array"})
    with pytest.raises(ValueError, match="compiles only"):
        make_batch_env("Reacher-v5", 2, "numba")


def test_unseeded_reset_after_a_seeded_one_goes_on_as_gymnasium():
    """Slots seeded alike share their start, yet each goes on from its own generator as Gymnasium's env does."""
    fast, slow = make_batch_env("Pendulum-v1", 3, "numba"), make_batch_env("Pendulum-v1", 3, "gymnasium")
    for env in (fast, slow):
        env.reset(seed=[7, 7, 8])
    np.testing.assert_array_equal(fast.reset()[0], slow.reset()[0])


def test_an_action_outside_a_discrete_space_is_refused():
    env = make_batch_env("Acrobot-v1", 2, "numba")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must be in 0\.\.2, got \[1, 3\]"):
        env.step(np.array([1, 3]))
