"""The cart-poles seen through a camera, and model-based runs that learn from their frames."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from click.testing import CliRunner
from gymnasium.utils.env_checker import check_env
from test_loop import StopAfter, metrics, tensors

import drrl.envs  # noqa: F401  (registers the envs)
from drrl.cli import main
from drrl.envs.pixels import FRAME_SIZE, VIEW_HALF_WIDTH, draw_frames
from drrl.models.frames import STILL, Encoding, FrameAutoencoder, fit_autoencoder
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.loop import run
from drrl.training.train import prepare, resume, subscribers, train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

PIXEL = 2 * VIEW_HALF_WIDTH / FRAME_SIZE  # metres a pixel


def centroid_column(frame: np.ndarray, rows: slice) -> float:
    """The brightness-weighted mean column (in pixels, from the left edge) of ``rows`` of a frame."""
    weights = frame[rows].astype(float).sum(0)
    return float((weights * (np.arange(FRAME_SIZE) + 0.5)).sum() / weights.sum())


def test_the_cart_is_drawn_where_it_stands_to_a_fraction_of_a_pixel():
    cart_rows = slice(FRAME_SIZE // 2 - 1, FRAME_SIZE // 2 + 1)  # the two rows through the axle: the cart alone
    for s in (-2.0, -0.33, 0.0, 0.41, 1.7):
        frame = draw_frames(np.array([[s, 0.0, np.pi, 0.0]]))[0]  # pole hanging down, out of the cart's rows
        expected = (s + VIEW_HALF_WIDTH) / PIXEL
        assert abs(centroid_column(frame, cart_rows) - expected) < 0.05
    a, b = draw_frames(np.array([[0.0, 0, 0, 0], [0.3 * PIXEL, 0, 0, 0]]))
    assert (a != b).any()  # a third of a pixel shows


@pytest.mark.parametrize("theta", [-0.6, -0.2, 0.0, 0.35])
def test_the_pole_leans_as_the_angle_says(theta):
    frame = draw_frames(np.array([[0.0, 0.0, theta, 0.0]]))[0]
    # the pole's row 7 pixels above the axle: its centre lies 7 · tan θ pixels to the side (θ positive leans to +s)
    row = FRAME_SIZE // 2 - 8
    column = centroid_column(frame, slice(row, row + 1))
    height = FRAME_SIZE / 2 - (row + 0.5)
    assert abs(column - (FRAME_SIZE / 2 + height * np.tan(theta))) < 0.3


def test_the_pixel_envs_pass_the_checker_and_the_batch_sees_what_the_single_env_sees():
    check_env(gym.make("drrl/CartPolePixels-v0").unwrapped)
    batch = gym.make_vec("drrl/CartPolePixels-v0", num_envs=3, vectorization_mode="vector_entry_point")
    single = gym.make("drrl/CartPolePixels-v0")
    observations, _ = batch.reset(seed=[5, 6, 7])
    first, _ = single.reset(seed=6)
    assert observations.shape == (3, 2, 64, 64) and observations.dtype == np.uint8
    np.testing.assert_array_equal(observations[:, 0], observations[:, 1])  # a start shows its frame twice
    np.testing.assert_array_equal(observations[1], first)
    actions = np.array([[0.5], [-0.2], [1.0]])
    for _ in range(5):
        previous = observations
        observations, *_ = batch.step(actions)
        expected, *_ = single.step(actions[1])
        np.testing.assert_array_equal(observations[:, 0], previous[:, 1])  # (previous, current)
    np.testing.assert_array_equal(observations[1], expected)
    np.testing.assert_array_equal(observations[:, 1], draw_frames(batch.unwrapped.state))


def test_an_env_that_restarts_shows_its_start_frame_twice():
    batch = gym.make_vec("drrl/CartPolePixels-v0", num_envs=2, vectorization_mode="vector_entry_point")
    batch.reset(seed=[0, 1])
    push = np.array([[1.0], [0.0]])  # env 0 pushed hard fails within the horizon; env 1 runs on
    for _ in range(200):
        _, _, terminated, _, _ = batch.step(push)
        if terminated[0]:
            break
    assert terminated[0] and not terminated[1]
    observations, *_ = batch.step(push)  # env 0 restarts on this step
    np.testing.assert_array_equal(observations[0, 0], observations[0, 1])
    assert (observations[1, 0] != observations[1, 1]).any()


@pytest.mark.slow
def test_the_frame_autoencoder_learns_to_redraw_frames_and_reads_motion_off_its_codes():
    rng = np.random.default_rng(0)
    states = np.zeros((256, 4))
    states[:, 0], states[:, 2] = rng.uniform(-2, 2, 256), rng.uniform(-0.7, 0.7, 256)
    moved = states.copy()
    moved[:, 0] += 0.05  # the cart 5 cm on, the pole still
    observations = np.stack([draw_frames(states), draw_frames(moved)], axis=1)  # (previous, current)
    torch.manual_seed(0)
    model = FrameAutoencoder((2, 64, 64), latent=4)
    pixels = torch.as_tensor(observations[:, 1:]).float() / 255

    def loss() -> float:
        with torch.no_grad():
            return float(torch.nn.functional.binary_cross_entropy(model.decode(model(pixels)), pixels))

    before = loss()
    fit = fit_autoencoder(model, observations, updates=150, seed=0)
    assert loss() < 0.5 * before and fit.updates == 150
    features = model.encode(observations)
    assert features.shape == (256, 8) and features.dtype == np.float32
    np.testing.assert_allclose(fit.features, features, rtol=1e-5, atol=1e-5)  # the fit's own pass gives the same
    np.testing.assert_allclose(features.mean(0), 0, atol=1e-4)
    moving = model.feature_std > STILL  # the others are divided by STILL, not blown up to unit size
    np.testing.assert_allclose(features.std(0, ddof=1)[moving], 1, atol=1e-3)
    assert (features.std(0)[~moving] < 1).all()
    with torch.no_grad():  # independently: the newest code, then its change since the older frame
        z = model(torch.as_tensor(observations.reshape(512, 1, 64, 64))).reshape(256, 2, 4)
        raw = torch.cat([z[:, 1], z[:, 1] - z[:, 0]], dim=1)
    expected = (raw - model.feature_mean) / model.feature_std
    np.testing.assert_allclose(features, expected.numpy(), rtol=1e-4, atol=1e-4)
    still = np.stack([draw_frames(moved)] * 2, axis=1)  # no motion: the changes are 0 before standardising
    raw_still = model.encode(still) * model.feature_std.numpy() + model.feature_mean.numpy()
    np.testing.assert_allclose(raw_still[:, 4:], 0, atol=1e-5)
    assert model.draw(features[:3]).shape == (3, 1, 64, 64)
    assert (z.abs() <= 1).all()  # keypoints: expected positions across the frame
    fresh = states[::-1] + np.array([0.1, 0, 0, 0])  # the pairs moved 10 cm: frames the fit has not seen
    codes = model.encode(np.stack([draw_frames(fresh), draw_frames(fresh)], axis=1))
    assert linear_fit(codes, fresh[:, 0]) > 0.95  # the cart's place, read linearly off the keypoints
    env = Encoding(gym.make_vec("drrl/CartPolePixels-v0", num_envs=2, vectorization_mode="vector_entry_point"), model)
    encoded, _ = env.reset(seed=0)
    assert encoded.shape == (2, 8) and env.single_observation_space.shape == (8,)
    frames = draw_frames(env.unwrapped.state)
    np.testing.assert_allclose(encoded, model.encode(np.stack([frames, frames], axis=1)), rtol=1e-6)


def linear_fit(x: np.ndarray, y: np.ndarray) -> float:
    """R² of y's least-squares fit by an affine function of x."""
    inputs = np.c_[x, np.ones(len(x))]
    residual = y - inputs @ np.linalg.lstsq(inputs, y, rcond=None)[0]
    return 1 - residual.var() / y.var()


def test_a_model_free_run_on_frames_asked_for_is_refused_in_one_line(tmp_path):
    result = CliRunner().invoke(main, ["train", "cartpole-pixels", "--model-free", "--out", str(tmp_path / "run")])
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1 and "add --model-based" in errors[0], result.output
    assert not (tmp_path / "run").exists()


def test_compare_on_frames_runs_only_the_model_based_method_and_refuses_the_others_in_one_line(tmp_path):
    command = ["compare", "--env", "cartpole-pixels", "--method", "SyS-PGPE", "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(main, command)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 2 and len(errors) == 1 and "--method 'model-based PGPE'" in errors[0], result.output
    assert not (tmp_path / "out").exists()


# a pixel run that only needs to work: a few updates of everything
PIXELS = TrainConfig.model_validate(
    dict(
        env="cartpole-pixels",
        policy="rnn:2",
        popsize=4,
        episodes_per_candidate=2,
        budget=6,
        eval_episodes=3,
        seed=2,
        model_based=dict(
            hidden=(8,),
            unfold=2,
            overshoot=2,
            latent_size=2,
            fit_updates=20,
            refit_updates=20,
            frame_updates=6,
            frame_refit_updates=4,
            generations_per_iteration=2,
            patience=2,
            initial_episodes=2,
            episodes_per_iteration=2,
        ),
    )
)


@pytest.mark.slow
def test_a_pixel_run_learns_on_latents_resumes_exactly_and_eval_and_render_read_frames_through_its_encoder(tmp_path):
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    counters = train(PIXELS, whole)
    assert counters.real_episodes == 6 and counters.imagined_episodes > 0
    checkpoint = RunFolder(whole).load_checkpoint()
    world = checkpoint["world"]
    assert world["frames"]["observations"].dtype == torch.uint8
    assert world["frames"]["observations"].shape[1:] == (2, 64, 64)
    assert world["buffer"]["observations"].shape[1:] == (4,)  # the model learns on the latent state
    assert len(world["frames"]["observations"]) == counters.real_steps + counters.real_episodes
    setup = prepare(PIXELS)
    with pytest.raises(KeyboardInterrupt):
        run(setup, [*subscribers(RunFolder.create(stopped), progress=False), StopAfter(1)])
    resume(stopped)
    assert metrics(stopped) == metrics(whole)
    final, expected = tensors(RunFolder(stopped).load_checkpoint()), tensors(checkpoint)
    assert final.keys() == expected.keys() and all(torch.equal(final[key], expected[key]) for key in expected)
    result = CliRunner().invoke(main, ["eval", str(whole), "--episodes", "4"])
    assert result.exit_code == 0, result.output
    assert "drrl/CartPolePixels-v0" in result.output and "balanced:" in result.output
    result = CliRunner().invoke(main, ["render", str(whole), "--out", str(tmp_path / "episode.gif")])
    assert result.exit_code == 0 and (tmp_path / "episode.gif").stat().st_size > 0, result.output


@pytest.mark.slow
def test_a_run_whose_encoder_weights_another_version_made_is_refused_in_one_line(tmp_path):
    folder = RunFolder(tmp_path / "run")
    train(PIXELS, folder.path)
    checkpoint = folder.load_checkpoint()
    checkpoint["world"]["autoencoder"]["encoder.0.weight"] = torch.zeros(8, 1, 4, 4)  # another encoder's first layer
    folder.save_checkpoint(checkpoint)
    saved = (folder.path / "checkpoint.safetensors").read_bytes()
    for command in (
        ["eval", str(folder.path), "--episodes", "2"],
        ["render", str(folder.path), "--out", str(tmp_path / "episode.gif")],
        ["train", "--resume", str(folder.path)],
    ):
        result = CliRunner().invoke(main, command)
        errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
        assert result.exit_code != 0 and len(errors) == 1, result.output
        assert "FrameAutoencoder weights do not fit" in errors[0] and "Traceback" not in result.output
    assert (folder.path / "checkpoint.safetensors").read_bytes() == saved
    assert not (tmp_path / "episode.gif").exists()
