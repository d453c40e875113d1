import numpy as np
import pytest
import torch
from click.testing import CliRunner

from drrl.cli import main
from drrl.models import Episode, EpisodeBuffer, FitSettings, LinearModel, PolynomialModel
from drrl.models.kinds import fit_model, make_model, remake
from drrl.models.polynomial import BOUND
from drrl.models.quality import k_step_errors

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

SETTINGS = FitSettings(unfold=2, overshoot=6, learn_reward=False)
DT = 0.05


def duffing_episodes(count, steps, seed):
    """x' = x + dt·v, v' = v + dt·(−x − x³ − 0.2 v + a): a driven Duffing oscillator, polynomial of degree 3 in
    (x, v, a), so the model's features hold it exactly (in normalised units too: an affine change of variables)."""
    rng = np.random.default_rng(seed)
    episodes = []
    for _ in range(count):
        observations = [rng.uniform(-1.5, 1.5, 2)]
        actions = rng.uniform(-1, 1, (steps, 1))
        for (action,) in actions:
            x, v = observations[-1]
            observations.append(np.array([x + DT * v, v + DT * (-x - x**3 - 0.2 * v + action)]))
        episodes.append(
            Episode(np.array(observations, np.float32), actions.astype(np.float32), np.zeros(steps, np.float32), False)
        )
    return episodes


def test_a_cubic_system_is_identified_where_the_linear_model_cannot_follow_it():
    training, held_out = EpisodeBuffer(duffing_episodes(8, 60, seed=0)), EpisodeBuffer(duffing_episodes(4, 60, seed=1))
    errors = {}
    for kind in ("polynomial", "linear"):
        model = make_model(kind, 2, 1)
        fit_model(model, training, SETTINGS, seed=0)
        errors[kind] = k_step_errors(model, held_out, 30)
    assert errors["polynomial"][-1] < 0.05  # in units of the per-step change, 30 steps ahead
    assert errors["linear"][-1] > 20 * errors["polynomial"][-1]


def test_thresholding_keeps_only_the_terms_the_system_has():
    """Δx = dt·v: of the 21 features only v's (and the constant, always kept) carries Δx; Δv needs x, x³, v, a and
    the cross terms the normalisation's offsets bring, not the action's square or the previous action."""
    model = PolynomialModel(2, 1)
    fit_model(model, EpisodeBuffer(duffing_episodes(8, 60, seed=0)), SETTINGS, seed=0)
    weight = model.weight[0]
    assert model.num_features == 6 + 10 + 5  # (x, v, a): 6 monomials of degree 2, 10 of degree 3; linear 5
    assert int((weight[:, 0] != 0).sum()) <= 2
    previous_action = model.num_features - 2
    assert weight[previous_action, 1] == 0 and 0 < int((weight[:, 1] != 0).sum()) < model.num_features // 2


def test_a_prediction_stays_within_its_bound_of_the_data():
    model = make_model("polynomial", 2, 1, members=2)
    fit_model(model, EpisodeBuffer(duffing_episodes(8, 60, seed=0)), SETTINGS, seed=0)
    far = torch.tensor([[50.0, -80.0], [0.1, 0.2]])
    with torch.no_grad():
        prediction, _ = model.step(far, torch.zeros(2, 1), model.initial_state(2))
    low = model.observation_mean - BOUND * model.observation_scale
    high = model.observation_mean + BOUND * model.observation_scale
    assert ((prediction.observations >= low[:, None]) & (prediction.observations <= high[:, None])).all()
    assert torch.isclose(prediction.observations[:, 0, 0], high[:, 0]).all()  # x far above: held at its bound


def test_a_remade_polynomial_model_has_its_kind_and_a_fit_gives_the_same_weights():
    model = make_model("polynomial", 2, 1, members=2)
    buffer = EpisodeBuffer(duffing_episodes(6, 40, seed=2))
    fit_model(model, buffer, SETTINGS, seed=3)
    again = remake(model, seed=9)
    assert type(again) is PolynomialModel and isinstance(again, LinearModel)
    fit_model(again, buffer, SETTINGS, seed=3)
    for name, tensor in model.state_dict().items():
        torch.testing.assert_close(again.state_dict()[name], tensor)


def test_a_model_based_run_uses_the_polynomial_model_from_the_command_line(tmp_path):
    args = [
        "train",
        "cartpole",
        "--model-based",
        "--model-kind",
        "polynomial",
        "--budget",
        "4",
        "--generations-per-iteration",
        "2",
    ]
    result = CliRunner().invoke(main, [*args, "--eval-episodes", "4", "--quiet", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "done: 2 iterations, 4 real episodes" in result.output
