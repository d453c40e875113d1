import numpy as np
import pytest
import torch
from test_models import linear_system_episodes

from drrl.models import Episode, EpisodeBuffer, FitSettings, LinearModel
from drrl.models.kinds import fit_model, make_model, remake
from drrl.models.linear import fit_linear
from drrl.models.quality import k_step_errors

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

SETTINGS = FitSettings(unfold=2, overshoot=6, learn_reward=False)


def delayed_system_episodes(count, steps, seed):
    """o_{t+1} = A o_t + B a_{t−1}: the oscillator of ``linear_system_episodes`` driven a step late, as a robot whose
    command acts one control period after it is sent."""
    delayed = []
    for episode in linear_system_episodes(count, steps, seed):
        late = np.concatenate([np.zeros_like(episode.actions[:1]), episode.actions[:-1]])
        observations = [episode.observations[0]]
        angle = 0.3
        a = 0.97 * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        for action in late:
            observations.append(a @ observations[-1] + np.array([0.0, 0.2]) * action[0])
        delayed.append(Episode(np.array(observations, np.float32), episode.actions, episode.rewards, False))
    return delayed


@pytest.mark.parametrize("system", [linear_system_episodes, delayed_system_episodes])
def test_least_squares_identifies_a_linear_system_and_one_a_step_late(system):
    training, held_out = EpisodeBuffer(system(8, 40, seed=1)), EpisodeBuffer(system(2, 40, seed=2))
    model = LinearModel(2, 1)
    untrained = k_step_errors(model, held_out, 20)
    [report] = fit_linear(model, training, SETTINGS)
    errors = k_step_errors(model, held_out, 20)  # in units of the per-step change
    assert report.stop == "least_squares" and report.updates == 0 and report.train_loss < 0.05
    assert errors[0] < 0.02 and errors[-1] < 0.1 and errors[-1] < untrained[-1] / 10


def test_without_the_previous_action_a_delayed_system_could_not_be_fitted():
    """The memory is what identifies the delay: the same fit with a_{t−1} zeroed out errs by far more."""
    training = EpisodeBuffer(delayed_system_episodes(8, 40, seed=1))
    model = LinearModel(2, 1)
    fit_linear(model, training, SETTINGS)
    with torch.no_grad():
        model.weight[:, 3] = 0.0  # the feature of a_{t−1}
    assert k_step_errors(model, EpisodeBuffer(delayed_system_episodes(2, 40, seed=2)), 1)[0] > 0.3


def test_a_known_linear_weight_is_recovered_in_closed_form():
    """Δo / std(Δo) is exactly linear in the features: the fitted weight is the generating one, up to the ridge."""
    model = LinearModel(2, 1)
    buffer = EpisodeBuffer(linear_system_episodes(10, 50, seed=4))
    fit_linear(model, buffer, SETTINGS)
    episode = buffer.episodes[0]
    with torch.no_grad():
        prediction, _ = model.step(
            torch.as_tensor(episode.observations[:-1]),
            torch.as_tensor(episode.actions),
            model.initial_state(len(episode)),
        )
    np.testing.assert_allclose(prediction.observations[0].numpy(), episode.observations[1:], atol=2e-3)


def test_each_member_is_fitted_on_its_own_episodes_and_disagrees_where_they_differ():
    model = make_model("linear", 2, 1, members=3)
    reports = fit_model(model, EpisodeBuffer(linear_system_episodes(10, 30, seed=5)), SETTINGS, seed=0)
    assert [report.held_out_episodes for report in reports] == [2, 2, 2]
    assert len({tuple(scale.tolist()) for scale in model.change_scale}) == 3
    observations, actions = torch.randn(4, 2), torch.randn(4, 1)
    with torch.no_grad():
        prediction, _ = model.step(observations, actions, model.initial_state(4))
    assert prediction.observations.shape == (3, 4, 2) and (model.disagreement(prediction) > 0).all()


def test_a_least_squares_fit_with_mirror_images_is_symmetric_and_counts_only_real_episodes_held_out():
    model = make_model("linear", 2, 1, members=3)
    buffer = EpisodeBuffer(linear_system_episodes(10, 30, seed=5))
    reports = fit_model(model, buffer, SETTINGS, seed=0, mirror=lambda o, a: (-o, -a))
    assert [report.held_out_episodes for report in reports] == [2, 2, 2]
    np.testing.assert_allclose(model.observation_mean.numpy(), 0.0, atol=1e-6)
    np.testing.assert_allclose(model.action_mean.numpy(), 0.0, atol=1e-6)


def test_a_remade_model_has_the_kind_and_shape_and_a_fit_gives_the_same_weights():
    model = make_model("linear", 2, 1, members=2)
    buffer = EpisodeBuffer(linear_system_episodes(10, 30, seed=5))
    fit_model(model, buffer, SETTINGS, seed=3)
    again = remake(model, seed=9)
    assert isinstance(again, LinearModel) and again.settings() == model.settings()
    fit_model(again, buffer, SETTINGS, seed=3)
    for name, tensor in model.state_dict().items():
        torch.testing.assert_close(again.state_dict()[name], tensor)
