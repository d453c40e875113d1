"""A user's own env, named the way Gymnasium names one in a module (``MODULE:ID``), trains from the command line,
and its run folder is read again by eval, render and resume in new processes, which import the module again."""

import subprocess
import sys
from pathlib import Path

import pytest

MODULE = '''
import gymnasium
import numpy as np
from gymnasium import spaces


class Drift(gymnasium.Env):
    """A point pushed along a line towards 0."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, render_mode=None):
        self.observation_space = spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.render_mode = render_mode

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-1.0, 1.0)
        return np.array([self.x], np.float32), {}

    def step(self, action):
        self.x += 0.1 * float(np.clip(action[0], -1.0, 1.0))
        return np.array([self.x], np.float32), -self.x**2, False, False, {}

    def render(self):
        return np.zeros((16, 16, 3), np.uint8)


gymnasium.register("Drift-v0", entry_point=Drift, max_episode_steps=20)
'''


def drrl(folder: Path, *args) -> subprocess.CompletedProcess:
    """``drrl`` as a user's shell runs it: the installed command, in ``folder``, a new process each time."""
    command = Path(sys.executable).with_name("drrl")
    return subprocess.run([command, *map(str, args)], cwd=folder, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("world", [[], ["--model-based"]])
@pytest.mark.slow
def test_a_user_s_env_in_a_module_trains_and_its_run_is_read_again(tmp_path, world):
    (tmp_path / "my_envs.py").write_text(MODULE)
    trained = drrl(tmp_path, "train", "--env", "my_envs:Drift-v0", *world, "--budget", 16, "--quiet", "--out", "run")
    assert trained.returncode == 0, trained.stderr
    assert '"env": "my_envs:Drift-v0"' in (tmp_path / "run" / "config.json").read_text()
    measured = drrl(tmp_path, "eval", "run", "--episodes", 3)
    assert measured.returncode == 0 and "Drift-v0" in measured.stdout, measured.stderr
    rendered = drrl(tmp_path, "render", "run", "--out", "run.gif")
    assert rendered.returncode == 0 and (tmp_path / "run.gif").stat().st_size > 0, rendered.stderr
    resumed = drrl(tmp_path, "train", "--resume", "run")
    assert resumed.returncode == 0 and "is complete" in resumed.stdout, resumed.stderr


@pytest.mark.parametrize(
    "env, message",
    [
        ("no_such_module:Drift-v0", "cannot import 'no_such_module' for the env 'no_such_module:Drift-v0': Module"),
        (
            "broken:Drift-v0",
            "cannot import 'broken' for the env 'broken:Drift-v0': ZeroDivisionError: division by zero",
        ),
        ("my envs:Drift-v0", "'my envs' is not a Python module name (MODULE:ID"),
        ("my_envs:Nothing-v0", "unknown environment 'Nothing-v0'"),
    ],
)
@pytest.mark.slow
def test_a_module_that_does_not_give_the_env_is_one_line(tmp_path, env, message):
    (tmp_path / "my_envs.py").write_text(MODULE)
    (tmp_path / "broken.py").write_text("1 / 0\n")
    result = drrl(tmp_path, "train", "--env", env, "--out", "run")
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "run").exists()
