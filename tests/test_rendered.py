"""Any rendering Gymnasium env seen through its camera (``Pixels/ID``), and a model-based run that learns from it."""

import gymnasium as gym
import numpy as np
import pytest
from click.testing import CliRunner
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env
from test_pixels import PIXELS

import drrl.envs  # noqa: F401  (registers the envs and the Pixels/ family)
from drrl.cli import main
from drrl.envs.batch import choose_engine, is_frames, make_batch_env
from drrl.envs.registry import lookup
from drrl.envs.rendered import GreyFrames, following_env, rendering_env
from drrl.runs import RunFolder
from drrl.training.train import train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


class Painting(gym.Env):
    """An env whose observation is a fixed RGB picture."""

    def __init__(self, picture: np.ndarray):
        self.picture = picture
        self.observation_space = spaces.Box(0, 255, picture.shape, np.uint8)
        self.action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        return self.picture, {}

    def step(self, action):
        return self.picture, 0.0, False, False, {}


def test_a_frame_turns_grey_by_luma_and_shrinks_by_the_mean_of_each_cell():
    rng = np.random.default_rng(0)
    picture = rng.integers(0, 256, (128, 192, 3), dtype=np.uint8)
    grey = GreyFrames(Painting(picture), size=64).reset()[0]
    luma = picture.astype(float) @ [0.299, 0.587, 0.114]
    expected = luma.reshape(64, 2, 64, 3).mean(axis=(1, 3))  # 2 × 3 pixels a cell
    assert grey.dtype == np.uint8 and grey.shape == (64, 64)
    assert np.abs(grey - expected).max() <= 0.5 + 1e-3  # rounded to the nearest grey level
    with pytest.raises(ValueError, match="smaller than 64 × 64"):
        GreyFrames(Painting(picture[:50]), size=64)


def test_pixels_pendulum_is_the_pendulum_observed_by_its_last_two_frames():
    entry = lookup("Pixels/Pendulum-v1")
    assert entry.env_id == "Pixels/Pendulum-v1" and choose_engine(entry.env_id) == "gymnasium"
    env = gym.make(entry.env_id)
    check_env(env.unwrapped)
    plain = gym.make("Pendulum-v1")
    frames, _ = env.reset(seed=3)
    plain.reset(seed=3)
    assert frames.shape == (2, 64, 64) and frames.dtype == np.uint8
    assert np.array_equal(frames[0], frames[1])  # the start's frame twice
    for action in np.random.default_rng(0).uniform(-2, 2, (10, 1)).astype(np.float32):
        previous = frames
        frames, reward, *_ = env.step(action)
        assert reward == plain.step(action)[1]  # the task is the pendulum's own
        assert np.array_equal(frames[0], previous[1])  # the current frame becomes the previous one
    assert not np.array_equal(frames[0], frames[1])  # it swings
    for engine in ("gymnasium", "processes"):  # a worker process registers the id itself
        batch = make_batch_env(entry.env_id, 3, engine)
        assert is_frames(batch.single_observation_space)
        observations, _ = batch.reset(seed=[3, 4, 5])
        assert np.array_equal(observations[0], env.reset(seed=3)[0])
        batch.close()


def test_a_runner_that_runs_off_stays_in_the_frame_of_its_tracking_camera():
    def cheetah_pixels(env: gym.Env) -> int:  # its tan and pink limbs: red well above green, which floor and sky lack
        frame = env.render().astype(int)
        return int((frame[..., 0] - frame[..., 1] > 30).sum())

    seen = []
    for make in (following_env, rendering_env):
        env = make("HalfCheetah-v5", {"width": 64, "height": 64})
        env.reset(seed=0)
        at_start = cheetah_pixels(env)
        position = env.unwrapped.data.qpos.copy()
        position[0] += 10.0  # ten metres on
        env.unwrapped.set_state(position, env.unwrapped.data.qvel)
        seen.append((at_start, cheetah_pixels(env)))
        env.close()
    (followed_start, followed_on), (fixed_start, fixed_on) = seen
    assert fixed_start > 20 and fixed_on == 0  # Gymnasium's default camera stays where the run began
    assert followed_on > 0.5 * followed_start > 20


@pytest.mark.parametrize(
    "name, message",
    [
        ("Pixels/cartpole", "only ids without a namespace.*cartpole-pixels"),
        ("Pixels/Nopendulum-v1", "unknown environment 'Nopendulum-v1'"),
    ],
)
def test_an_id_that_cannot_be_seen_is_refused_in_one_line(name, message):
    with pytest.raises(ValueError, match=message):
        lookup(name)
    result = CliRunner().invoke(main, ["train", name, "--model-based"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert len([line for line in result.output.splitlines() if line.startswith("Error")]) == 1


@pytest.mark.slow
def test_a_model_based_run_learns_from_a_gymnasium_envs_frames_and_eval_and_render_read_them(tmp_path):
    config = PIXELS.model_copy(update={"env": "Pixels/Pendulum-v1", "max_steps": 30})  # test_pixels's tiny run
    counters = train(config, tmp_path / "run")
    assert counters.real_episodes == 6 and counters.real_steps == 6 * 30 and counters.imagined_episodes > 0
    world = RunFolder(tmp_path / "run").load_checkpoint()["world"]
    assert world["frames"]["observations"].shape[1:] == (2, 64, 64)
    result = CliRunner().invoke(main, ["eval", str(tmp_path / "run"), "--episodes", "2"])
    assert result.exit_code == 0, result.output
    assert "Pixels/Pendulum-v1" in result.output
    result = CliRunner().invoke(main, ["render", str(tmp_path / "run"), "--out", str(tmp_path / "episode.gif")])
    assert result.exit_code == 0 and (tmp_path / "episode.gif").stat().st_size > 0, result.output
