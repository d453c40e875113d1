import gymnasium
import pytest
import torch
from gymnasium import spaces
from hypothesis import settings

# Hypothesis's per-example deadline would make every property test a timed test, which a busy shared machine fails;
# speed is measured in benchmarks/, not here
settings.register_profile("untimed", deadline=None)
settings.load_profile("untimed")


class WordObserving(gymnasium.Env):
    """An env observing words, a space drrl cannot give a policy: for the refusals of unsupported spaces."""

    observation_space = spaces.Text(max_length=4)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return "word", {}

    def step(self, action):
        return "word", 0.0, True, False, {}


gymnasium.register("tests/WordObserving-v0", entry_point=WordObserving, max_episode_steps=10)


@pytest.fixture(scope="module")
def one_thread():
    """Tiny matrices: one thread is fastest, and immune to a busy machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
