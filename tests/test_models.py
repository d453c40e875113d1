import warnings

import gymnasium
import numpy as np
import pytest
import torch
from hypothesis import assume, given
from hypothesis import strategies as st

from drrl.envs.batch import make_batch_env
from drrl.envs.cartpole import BalanceTask, PartiallyObservedTask, SwingUpTask, failure_reward
from drrl.envs.registry import lookup
from drrl.models import Episode, EpisodeBuffer, EpisodeRecorder, FitSettings, ImaginedEnv, TaskKnowledge, WorldModel
from drrl.models import fit as fit_module
from drrl.models.data import STILL, with_mirror_images
from drrl.models.fit import clip_member_gradients, fit, split_episodes, split_offsets
from drrl.models.kinds import MODEL_KINDS, make_model
from drrl.models.outcome import fit_outcome
from drrl.models.quality import k_step_errors, model_quality_report
from drrl.policies import linear
from drrl.rollout import evaluate

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def random_inputs(batch=3, length=7, observation_size=4, action_size=1, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return (
        torch.randn(batch, length, observation_size, generator=generator),
        torch.randn(batch, length, action_size, generator=generator),
    )


def linear_system_episodes(count, steps, seed):
    """o_{t+1} = A o_t + B a_t: a damped oscillator driven by random actions."""
    angle = 0.3
    a = 0.97 * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    b = np.array([[0.0], [0.2]])
    rng = np.random.default_rng(seed)
    episodes = []
    for _ in range(count):
        observations = [rng.uniform(-1, 1, 2)]
        actions = rng.uniform(-1, 1, (steps, 1))
        for action in actions:
            observations.append(a @ observations[-1] + b @ action)
        episodes.append(
            Episode(np.array(observations, np.float32), actions.astype(np.float32), np.zeros(steps, np.float32), False)
        )
    return episodes


# ------------------------------------------------------------------------------------------------ the network
@pytest.mark.parametrize(
    "kind, hidden", [("rnn", (8,)), ("lstm", (8,)), ("rnn", (8, 6)), ("lstm", (8, 6)), ("mlp", (8, 6))]
)
def test_unfolding_and_overshooting_give_one_prediction_per_step(kind, hidden):
    model = WorldModel(4, 1, hidden, kind)
    observations, actions = random_inputs(batch=3, length=7)
    prediction = model.unfold(observations, actions, observed_steps=3)  # 3 observed + 4 overshooting steps
    assert prediction.observations.shape == (1, 3, 7, 4)  # members, windows, steps, observation
    assert prediction.rewards.shape == prediction.ends.shape == (1, 3, 7)
    assert ((prediction.ends > 0) & (prediction.ends < 1)).all()
    assert len(model.initial_state(5)) == len(hidden) * {"rnn": 1, "lstm": 2, "mlp": 0}[kind]


def test_a_feed_forward_model_is_a_tanh_network_of_the_current_observation_and_action_alone():
    """kind "mlp": each step is Linear → tanh → Linear → tanh → Linear on (normalised o_t, a_t), whatever came
    before, its output the change (in units of the data's), the reward and the end's logit."""
    torch.manual_seed(0)
    model = WorldModel(4, 1, (8, 6), "mlp")
    model.set_scales(
        {
            "observation_mean": torch.randn(1, 4),
            "observation_scale": torch.rand(1, 4) + 0.5,
            "change_scale": torch.rand(1, 4) + 0.5,
        }
    )
    layers = [torch.nn.Linear(5, 8), torch.nn.Tanh(), torch.nn.Linear(8, 6), torch.nn.Tanh(), torch.nn.Linear(6, 6)]
    weights = [*zip(model.input_weights, model.biases, strict=True), (model.readout_weight, model.readout_bias)]
    with torch.no_grad():
        for linear_layer, (w, b) in zip(layers[::2], weights, strict=True):
            linear_layer.weight.copy_(w[0].T)
            linear_layer.bias.copy_(b[0, 0])
    network = torch.nn.Sequential(*layers)
    observation, action = torch.randn(3, 4), torch.randn(3, 1)
    y = network(torch.cat([(observation - model.observation_mean) / model.observation_scale, action], dim=-1))
    for history in range(3):  # after 0, 1 or 2 other steps: no memory
        state = model.initial_state(3)
        for _ in range(history):
            _, state = model.step(torch.randn(3, 4), torch.randn(3, 1), state)
        prediction, state = model.step(observation, action, state)
        assert state == []
        torch.testing.assert_close(prediction.observations[0], observation + y[:, :4] * model.change_scale)
        torch.testing.assert_close(prediction.ends[0], torch.sigmoid(y[:, 5]))


@pytest.mark.parametrize("kind", ["rnn", "lstm"])
def test_a_layer_computes_what_torchs_own_cell_computes(kind):
    """The batched layers against nn.RNNCell (3.4: s_t = tanh(W x_t + B s_{t−1} + b)) and nn.LSTMCell."""
    torch.manual_seed(0)
    model = WorldModel(4, 1, (8,), kind)
    cell = (torch.nn.RNNCell if kind == "rnn" else torch.nn.LSTMCell)(5, 8)
    with torch.no_grad():
        cell.weight_ih.copy_(model.input_weights[0][0].T)
        cell.weight_hh.copy_(model.recurrent_weights[0][0].T)
        cell.bias_ih.copy_(model.biases[0][0, 0])
        cell.bias_hh.zero_()
    state, reference = model.initial_state(3), None
    for _ in range(3):
        observation, action = torch.randn(3, 4), torch.randn(3, 1)
        _, state = model.step(observation, action, state)
        x = torch.cat([observation, action], dim=-1)  # the scales are 0 and 1 until set_scales
        reference = cell(x, reference)
        expected = [reference] if kind == "rnn" else list(reference)
        for ours, theirs in zip(state, expected, strict=True):
            torch.testing.assert_close(ours[0], theirs)


@pytest.mark.parametrize("kind", ["rnn", "lstm"])
def test_the_gradient_of_the_last_overshooting_step_reaches_the_first_unfolded_step(kind):
    model = WorldModel(4, 1, (8, 8), kind)
    observations, actions = random_inputs(length=10)
    observations.requires_grad_(True)
    model.unfold(observations, actions, observed_steps=4).observations[:, -1].sum().backward()
    assert observations.grad[:, 0].abs().sum() > 0  # back-propagation through all 10 shared-weight copies
    assert model.recurrent_weights[0].grad.abs().sum() > 0


@pytest.mark.parametrize("future_inputs", ["predictions", "zeros"])
def test_the_overshooting_part_reads_the_models_predictions_not_the_observations(future_inputs):
    model = WorldModel(4, 1, (8,), future_inputs=future_inputs)
    observations, actions = random_inputs(length=8)
    prediction = model.unfold(observations, actions, observed_steps=3)
    changed = observations.clone()
    changed[:, 3:] += 10.0  # observations of the future part: must not be read
    torch.testing.assert_close(model.unfold(changed, actions, observed_steps=3).observations, prediction.observations)
    # and the prediction of each future step is fed back: unroll by hand
    state, previous = model.initial_state(3), None
    for t in range(8):
        fed = observations[:, t] if t < 3 else previous.observations
        previous, state = model.step(fed, actions[:, t], state, t < 3)
        torch.testing.assert_close(previous.observations, prediction.observations[:, :, t])
        torch.testing.assert_close(previous.rewards, prediction.rewards[:, :, t])
    # the observed part is read
    changed = observations.clone()
    changed[:, 2] += 1.0
    assert not torch.allclose(
        model.unfold(changed, actions, observed_steps=3).observations[:, :, 5], prediction.observations[:, :, 5]
    )


def test_zero_future_inputs_ignore_the_fed_back_observation():
    model = WorldModel(2, 1, (8,), future_inputs="zeros")
    state = model.initial_state(1)
    action = torch.zeros(1, 1)
    first, _ = model.step(torch.tensor([[1.0, 2.0]]), action, state, observed=False)
    second, _ = model.step(torch.tensor([[-3.0, 0.5]]), action, state, observed=False)
    # same network output (the change), added to different bases
    torch.testing.assert_close(
        first.observations - torch.tensor([[1.0, 2.0]]), second.observations - torch.tensor([[-3.0, 0.5]])
    )
    observed, _ = model.step(torch.tensor([[-3.0, 0.5]]), action, state, observed=True)
    assert not torch.allclose(observed.observations, second.observations)


@pytest.mark.parametrize("kind", ["rnn", "lstm", "mlp"])
def test_the_model_learns_a_known_linear_system(kind):
    torch.manual_seed(0)
    training, held_out = (
        EpisodeBuffer(linear_system_episodes(8, 40, seed=1)),
        EpisodeBuffer(linear_system_episodes(2, 40, seed=2)),
    )
    model = WorldModel(2, 1, (32,), kind)
    model.set_scales(training.scales())
    untrained = k_step_errors(model, held_out, 10)
    [report] = fit(
        model,
        training,
        FitSettings(
            unfold=2,
            overshoot=6,
            learn_reward=False,
            lr=2e-2,
            batch_size=256,
            max_updates=100,
            validate_every=25,
            patience=20,
        ),
    )
    errors = k_step_errors(model, held_out, 10)  # in units of the per-step change
    assert report.stop == "max_updates" and report.valid_loss < 1.0
    assert errors[0] < 0.3 and errors[-1] < 0.5 and errors[-1] < untrained[-1] / 10


def test_a_feature_constant_within_each_episode_stays_put_in_imagination():
    """Like Baxter's targets: the same through an episode, different between episodes. Its change scale is STILL, so
    a model's read-out, trained or not, cannot move it."""
    rng = np.random.default_rng(0)
    episodes = [
        Episode(
            np.concatenate([e.observations, np.full((len(e) + 1, 1), rng.uniform(-1, 1), np.float32)], axis=1),
            e.actions,
            e.rewards,
            False,
        )
        for e in linear_system_episodes(6, 30, seed=3)
    ]
    buffer = EpisodeBuffer(episodes)
    scales = buffer.scales()
    assert scales["change_scale"][2] == STILL and scales["observation_scale"][2] > 0.1
    assert (scales["change_scale"][:2] > 0.01).all()
    model = WorldModel(3, 1, (16,))
    model.set_scales(scales)
    windows = buffer.windows(1, 19)
    with torch.no_grad():
        predicted = model.unfold(windows.observations, windows.actions, observed_steps=1).observations
    drift = (predicted[0, :, :, 2] - windows.observations[:, :1, 2]).abs().max()
    assert drift < 20 * STILL * 10  # 20 steps of read-outs of order one (untrained: |y| < 10)


@pytest.mark.parametrize(("episodes", "stop"), [(10, "patience"), (4, "max_updates")])
def test_a_fit_stops_early_on_its_held_out_loss_only_when_episodes_are_held_out(episodes, stop):
    """A tiny step size makes no validation improve on the last: with episodes held out (2 of 10) the fit stops
    after ``patience`` validations; with 4 episodes none is held out and the fit runs to ``max_updates``."""
    torch.manual_seed(0)
    model = WorldModel(2, 1, (8,))
    settings = FitSettings(unfold=2, overshoot=2, learn_reward=False, lr=1e-12, max_updates=40, validate_every=5)
    [report] = fit(model, EpisodeBuffer(linear_system_episodes(episodes, 20, seed=1)), settings, seed=0)
    assert (report.stop, report.updates) == ((stop, 25) if stop == "patience" else (stop, 40))
    assert report.held_out_episodes == (2 if stop == "patience" else 0)


# ------------------------------------------------------------------------------------------------ data
def test_windows_align_targets_and_mask_steps_past_the_end():
    observations = np.arange(6, dtype=np.float32)[:, None]  # o_0..o_5: 5 steps
    episode = Episode(observations, np.zeros((5, 1), np.float32), np.arange(1, 6, dtype=np.float32), True)
    windows = EpisodeBuffer([episode]).windows(unfold=2, overshoot=2)
    assert len(windows) == 4  # starts 0..3: every start with 2 observed steps inside the episode
    assert windows.observations[:, :, 0].tolist()[0] == [0, 1, 2, 3]
    assert windows.next_observations[:, :, 0].tolist()[0] == [1, 2, 3, 4]
    assert windows.mask.tolist()[3] == [1, 1, 0, 0]  # start 3: steps 3, 4 inside, then past the end
    assert windows.ends.tolist()[3] == [0, 1, 0, 0]  # terminated at its last step, masked after
    assert windows.rewards[1].tolist() == [2, 3, 4, 5]


def test_too_short_data_and_too_long_overshooting_are_clear_errors():
    buffer = EpisodeBuffer(linear_system_episodes(2, 10, seed=0))
    with pytest.raises(ValueError, match=r"too short for the unfolding.*longest of the 2 episode\(s\) has 10"):
        fit(WorldModel(2, 1, (4,)), buffer, FitSettings(unfold=12, overshoot=0))
    with pytest.raises(ValueError, match="overshooting horizon is longer than the data: 4 unfolded \\+ 8"):
        fit(WorldModel(2, 1, (4,)), buffer, FitSettings(unfold=4, overshoot=8))


def test_a_diverging_fit_stops_and_keeps_the_last_good_model(monkeypatch):
    loss = fit_module.window_losses
    calls = {"n": 0}

    def turns_nan(*args, **kwargs):
        calls["n"] += 1
        value = loss(*args, **kwargs)
        return value * float("nan") if calls["n"] > 40 else value

    monkeypatch.setattr(fit_module, "window_losses", turns_nan)
    torch.manual_seed(0)
    model = WorldModel(2, 1, (8,))
    initial = [p.detach().clone() for p in model.parameters()]
    with pytest.warns(RuntimeWarning, match="diverged"):
        [report] = fit(
            model,
            EpisodeBuffer(linear_system_episodes(4, 20, seed=0)),
            FitSettings(unfold=2, overshoot=2, max_updates=100, validate_every=10),
        )
    assert report.stop == "diverged" and report.updates < 100 and np.isfinite(report.valid_loss)
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert any(
        not torch.equal(p, q) for p, q in zip(model.parameters(), initial, strict=True)
    )  # trained until it broke


def test_the_recorder_keeps_each_sub_environments_first_episode_exactly():
    env = EpisodeRecorder(make_batch_env("cartpole", 3))
    policy = linear(4, 1, bias=False)
    params = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.5, 1.0, 8.0, 1.0], [-3.0, 0.0, 0.0, 0.0]])
    result = evaluate(policy, params, env, 1, seed=3)
    episodes = env.episodes()
    assert [len(e) for e in episodes] == [len(e.rewards) for e in episodes]
    assert sum(len(e) for e in episodes) == result.steps
    np.testing.assert_allclose([e.rewards.sum() for e in episodes], result.episode_returns[:, 0].numpy(), rtol=1e-6)
    assert [e.terminated for e in episodes] == result.terminated[:, 0].tolist()
    assert all(len(e.observations) == len(e) + 1 for e in episodes)


def test_the_buffer_round_trips_through_its_state_dict():
    buffer = EpisodeBuffer(linear_system_episodes(3, 5, seed=0))
    copy = EpisodeBuffer.from_state_dict(buffer.state_dict())
    assert len(copy) == 3 and copy.num_steps == 15
    for a, b in zip(buffer.episodes, copy.episodes, strict=True):
        np.testing.assert_array_equal(a.observations, b.observations)
        np.testing.assert_array_equal(a.actions, b.actions)


# ------------------------------------------------------------------------------------------------ ensemble, imagination
def cartpole_starts():
    return np.array([[0.1, 0.0, 0.05, 0.0], [-0.3, 0.0, -0.1, 0.0], [0.4, 0.0, 0.15, 0.0]], np.float32)


def test_ensemble_members_disagree_only_when_their_weights_differ():
    torch.manual_seed(0)
    ensemble = WorldModel(4, 1, (8,), members=3)
    observation, action = torch.randn(5, 4), torch.randn(5, 1)
    prediction, _ = ensemble.step(observation, action, ensemble.initial_state(5))
    assert prediction.observations.shape == (3, 5, 4)
    assert (ensemble.disagreement(prediction) > 0).all()
    with torch.no_grad():
        for tensor in [*ensemble.parameters(), *ensemble.buffers()]:
            tensor[1:] = tensor[0]
    prediction, _ = ensemble.step(observation, action, ensemble.initial_state(5))
    torch.testing.assert_close(ensemble.disagreement(prediction), torch.zeros(5))


@pytest.mark.parametrize("kind, hidden", [("rnn", (8,)), ("lstm", (8, 6)), ("mlp", (8, 6))])
def test_each_member_of_the_batched_ensemble_computes_what_it_would_alone(kind, hidden):
    torch.manual_seed(0)
    ensemble = WorldModel(4, 1, hidden, kind, members=3)
    ensemble.set_scales({"observation_mean": torch.randn(3, 4), "change_scale": torch.rand(3, 4) + 0.5})
    observations, actions = random_inputs(batch=5, length=6)
    together = ensemble.unfold(observations, actions, observed_steps=2)
    for k in range(3):
        alone = WorldModel(4, 1, hidden, kind)
        alone.load_state_dict({name: tensor[k : k + 1] for name, tensor in ensemble.state_dict().items()})
        torch.testing.assert_close(
            alone.unfold(observations, actions, observed_steps=2).observations[0], together.observations[k]
        )


def test_gradients_are_clipped_for_each_member_apart():
    small, large = torch.full((3,), 0.1), torch.full((3,), 10.0)  # norms 0.17 and 17.3
    weight = torch.zeros(2, 3, requires_grad=True)
    weight.grad = torch.stack([small, large])
    clip_member_gradients([weight], max_norm=1.0)
    torch.testing.assert_close(weight.grad[0], small)
    torch.testing.assert_close(weight.grad[1].norm(), torch.tensor(1.0), rtol=1e-5, atol=1e-5)


def _held_out_places(lengths: list[int], settings: FitSettings, offset: float) -> set[int]:
    """The places in the buffer of the episodes ``split_episodes`` holds out, for episodes of ``lengths``."""
    episodes = [
        Episode(np.zeros((n + 1, 1), np.float32), np.zeros((n, 1), np.float32), np.zeros(n, np.float32), False)
        for n in lengths
    ]
    training, held_out = split_episodes(EpisodeBuffer(episodes), settings, offset)
    assert max(len(episode) for episode in training.episodes) == max(lengths)  # training keeps a full window
    return {next(i for i, e in enumerate(episodes) if e is held) for held in held_out.episodes}


@given(
    lengths=st.lists(st.integers(1, 30), min_size=1, max_size=40),
    added=st.lists(st.integers(1, 30), max_size=20),
    holdout=st.sampled_from([0.0, 0.1, 0.2, 0.25, 0.5]),
    offset=st.floats(0, 1, exclude_max=True),
)
def test_an_episode_keeps_its_part_as_episodes_are_added(lengths, added, holdout, offset):
    """A fit started from the previous model's weights never trains on what the fit before it held out: as the
    buffer grows an episode keeps its part, but for the longest (trained on while it is the only one that long) and
    the first episodes (nothing is held out while ⌊h · E⌋ = 0); one place in 1 / h is held out, never a short one."""
    places = np.arange(len(lengths + added) + 1) * holdout + offset
    assume(not holdout or np.abs(places - np.round(places)).min() > 1e-9)  # on a boundary rounding decides
    settings = FitSettings(unfold=3, overshoot=0, holdout=holdout)
    before, after = _held_out_places(lengths, settings, offset), _held_out_places(lengths + added, settings, offset)
    longest_before, longest_after = max(lengths), max(lengths + added)
    assert {i for i in before if lengths[i] < longest_after} <= after
    if int(holdout * len(lengths)):
        assert {i for i in after if i < len(lengths) and lengths[i] < longest_before} <= before
    place = np.arange(len(lengths)) * holdout + offset
    systematic = set(np.flatnonzero(np.floor(place + holdout) > np.floor(place)).tolist())
    eligible = {i for i in systematic if lengths[i] >= settings.unfold} if int(holdout * len(lengths)) else set()
    assert before <= eligible and len(eligible - before) <= 1


def test_five_members_hold_out_five_different_fifths():
    lengths = [20] * 25
    offsets = split_offsets(7, 0, 5)
    parts = [_held_out_places(lengths, FitSettings(unfold=2, overshoot=2), offset) for offset in offsets]
    assert [len(part) for part in parts] == [5] * 5
    assert set().union(*parts) == set(range(25))


def test_ensemble_members_are_fitted_on_different_held_out_episodes():
    model = WorldModel(2, 1, (8,), members=3)
    reports = fit(
        model,
        EpisodeBuffer(linear_system_episodes(10, 20, seed=0)),
        FitSettings(unfold=2, overshoot=2, max_updates=20, validate_every=10),
    )
    assert [report.held_out_episodes for report in reports] == [2, 2, 2]
    assert len({report.valid_loss for report in reports}) == 3
    assert len({tuple(scale.tolist()) for scale in model.change_scale}) == 3  # each member's own training split


def negated(observations, actions):
    """The linear system's reflection symmetry: o_{t+1} = A o_t + B a_t holds for (−o, −a) as for (o, a)."""
    return -observations, -actions


def test_mirror_images_are_appended_once_per_episode_so_parts_stay_parts():
    episodes = linear_system_episodes(4, 6, seed=0)
    whole, part = with_mirror_images([EpisodeBuffer(episodes), EpisodeBuffer(episodes[1:3])], negated)
    assert len(whole) == 8 and whole.episodes[:4] == episodes
    assert part.episodes[:2] == episodes[1:3] and part.episodes[2] is whole.episodes[5]  # the same image objects
    image, original = whole.episodes[4], episodes[0]
    np.testing.assert_array_equal(image.observations, -original.observations)
    np.testing.assert_array_equal(image.actions, -original.actions)
    assert image.rewards is original.rewards and image.terminated == original.terminated


def test_a_fit_with_mirror_images_trains_on_them_and_counts_only_real_episodes_held_out():
    model = WorldModel(2, 1, (8,), members=3)
    settings = FitSettings(unfold=2, overshoot=2, max_updates=20, validate_every=10)
    reports = fit(model, EpisodeBuffer(linear_system_episodes(10, 20, seed=0)), settings, mirror=negated)
    assert [report.held_out_episodes for report in reports] == [2, 2, 2]
    # every member's training data is symmetric about 0, whichever episodes it holds out
    np.testing.assert_allclose(model.observation_mean.numpy(), 0.0, atol=1e-6)
    unmirrored = WorldModel(2, 1, (8,), members=3)
    fit(unmirrored, EpisodeBuffer(linear_system_episodes(10, 20, seed=0)), settings)
    assert np.abs(unmirrored.observation_mean.numpy()).max() > 1e-3


def test_the_imagined_env_is_a_vector_env_that_evaluate_runs_unchanged():
    torch.manual_seed(0)
    ensemble = WorldModel(4, 1, (8,), members=2)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    task = TaskKnowledge(reward=lookup("drrl/CartPole-v0").reward)
    env = ImaginedEnv(ensemble, cartpole_starts(), 4 * 3, action_space, horizon=20, task=task)
    observations, _ = env.reset(seed=[11, 12, 13] * 4)
    assert observations.shape == (12, 4)
    assert {tuple(o) for o in observations} <= {tuple(s) for s in cartpole_starts()}  # real starts only
    np.testing.assert_array_equal(observations[:3], observations[3:6])  # same seed, same start
    policy = linear(4, 1, bias=False)
    params = torch.randn(4, 4, generator=torch.Generator().manual_seed(0))
    first = evaluate(policy, params, env, 3, seed=5)
    again = evaluate(policy, params, env, 3, seed=5)
    torch.testing.assert_close(first.episode_returns, again.episode_returns)
    assert first.steps <= 12 * 20 and first.episodes == 12
    assert (first.episode_returns <= 0).all()  # the thesis's reward 5.8 is never positive


def test_imagined_observations_are_completed_before_the_reward_and_the_policy_read_them():
    def complete(previous, predicted):  # entry 0 counts the steps, whatever the model predicts
        completed = predicted.copy()
        completed[:, 0] = previous[:, 0] + 1
        return completed

    seen = []

    def reward(observations, steps):
        seen.append(observations[:, 0].copy())
        return np.zeros(len(observations)), np.zeros(len(observations), dtype=bool)

    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    env = ImaginedEnv(
        WorldModel(4, 1, (8,)), cartpole_starts(), 3, action_space, 10, TaskKnowledge(reward, None, complete)
    )
    first, _ = env.reset(seed=[1, 2, 3])
    for step in range(1, 4):
        observations = env.step(np.zeros((3, 1), np.float32))[0]
        np.testing.assert_allclose(observations[:, 0], first[:, 0] + step, rtol=1e-6)
        np.testing.assert_array_equal(seen[-1], observations[:, 0])


def test_the_imagined_env_can_use_the_models_own_reward_and_penalise_disagreement():
    torch.manual_seed(0)
    ensemble = WorldModel(4, 1, (8,), members=3)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    plain = ImaginedEnv(ensemble, cartpole_starts(), 2, action_space, horizon=5)
    penalised = ImaginedEnv(ensemble, cartpole_starts(), 2, action_space, horizon=5, disagreement_penalty=1.0)
    rewards = []
    for env in (plain, penalised):
        env.reset(seed=[1, 2])
        rewards.append(env.step(np.zeros((2, 1), np.float32))[1])
    assert (rewards[1] < rewards[0]).all()


def test_a_learned_outcome_tells_the_cartpoles_failures_and_pays_them_as_the_task_does():
    env = EpisodeRecorder(make_batch_env("cartpole", 40))
    env.reset(seed=0)
    policy = linear(4, 1, bias=False)
    evaluate(policy, 0.5 * torch.randn(40, 4, generator=torch.Generator().manual_seed(0)), env, 1, seed=None)
    buffer = EpisodeBuffer(env.episodes())
    outcome = fit_outcome(buffer, failure_reward, updates=600, seed=0)
    rng = np.random.default_rng(1)
    inside = np.zeros((200, 4), np.float32)  # well inside the bounds: |s| ≤ 1, |θ| ≤ 0.3
    inside[:, 0], inside[:, 2] = rng.uniform(-1, 1, 200), rng.uniform(-0.3, 0.3, 200)
    beyond = inside.copy()
    beyond[:, 2] = np.sign(inside[:, 2]) * rng.uniform(0.8, 1.0, 200)  # the pole past 0.7 rad
    steps = np.full(200, 30)
    rewards, ends = outcome(inside, steps)
    assert not ends.any() and (rewards >= -1).all() and (rewards <= 0).all()  # within the real steps' range
    rewards, ends = outcome(beyond, steps)
    assert ends.mean() > 0.95 and (rewards[ends] == -2.0 * (200 - 30)).all()  # 5.8's failure, from the step


def grouped_and_every_member(kind: str, num_envs: int) -> tuple[ImaginedEnv, ImaginedEnv]:
    """Imagined episodes of horizon 3 in a three-member ensemble of ``kind``: each stepped by its own member, and
    every member stepping every episode (a vanishing disagreement penalty asks for that)."""
    ensemble = make_model(kind, 4, 1, hidden=(8,), members=3, seed=0)
    if kind == "linear":  # built with zero weights, which least squares would set
        with torch.no_grad():
            ensemble.weight.normal_(0.0, 0.1, generator=torch.Generator().manual_seed(0))
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    return (
        ImaginedEnv(ensemble, cartpole_starts(), num_envs, action_space, horizon=3),
        ImaginedEnv(ensemble, cartpole_starts(), num_envs, action_space, horizon=3, disagreement_penalty=1e-30),
    )


@pytest.mark.parametrize("kind", MODEL_KINDS)
def test_each_imagined_episode_is_stepped_by_its_own_member_alone(kind):
    """Grouping the episodes by member (one member steps each) gives what every member stepping every episode
    gives for the episode's own member, across restarts, which keep the layout (and set a model's memory, e.g. the
    linear model's previous action, as a new episode's)."""
    own, every = grouped_and_every_member(kind, 7)
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 7, 1)).astype(np.float32)
    for env in (own, every):
        env.reset(seed=list(range(7)))
    assert own._slots.numel() < every._slots.numel()
    layout = own._slots.clone()
    for action in actions:
        mine, theirs = own.step(action), every.step(action)
        np.testing.assert_allclose(mine[0], theirs[0], rtol=1e-5, atol=1e-6)  # next observations
        np.testing.assert_array_equal(mine[3], theirs[3])  # the same restarts
    torch.testing.assert_close(own._member, every._member)
    assert len(set(own._member.tolist())) > 1
    torch.testing.assert_close(own._slots, layout)


@pytest.mark.parametrize("kind", MODEL_KINDS)
def test_a_member_no_episode_drew_is_not_stepped_and_the_others_predict_bit_for_bit_as_before(kind):
    """Candidates compared on common starts share each episode's member: a generation of one episode a candidate
    draws one member for all, and only that member is stepped, predicting exactly what it does in the ensemble."""
    shared, every = grouped_and_every_member(kind, 6)
    for env in (shared, every):
        env.reset(seed=[11] * 6)
    assert len(shared._stepping) == 1 and len(every._stepping) == 3
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 6, 1)).astype(np.float32)
    for action in actions:  # across restarts (horizon 3), which keep each env's member
        mine, theirs = shared.step(action), every.step(action)
        np.testing.assert_array_equal(mine[0], theirs[0])
        np.testing.assert_array_equal(mine[3], theirs[3])


# ------------------------------------------------------------------------------------------------ quality report
def test_the_quality_report_plots_k_step_errors_of_each_variant(tmp_path):
    training, held_out = (
        EpisodeBuffer(linear_system_episodes(6, 30, seed=1)),
        EpisodeBuffer(linear_system_episodes(2, 30, seed=2)),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        curves = model_quality_report(
            training,
            held_out,
            tmp_path / "quality.png",
            max_k=8,
            hidden=(16,),
            settings=FitSettings(unfold=2, overshoot=4, learn_reward=False, lr=1e-2, max_updates=100),
        )
    assert len(curves) == 3 and all(errors.shape == (8,) and np.isfinite(errors).all() for errors in curves.values())
    assert (tmp_path / "quality.png").stat().st_size > 1000


@pytest.mark.parametrize(
    "env_id, task",
    [
        ("drrl/CartPole-v0", BalanceTask()),
        ("drrl/CartPolePO-v0", PartiallyObservedTask()),
        ("drrl/CartPoleSwingUp-v0", SwingUpTask()),
    ],
)
def test_known_rewards_on_observations_equal_the_tasks_rewards_on_states(env_id, task):
    states = np.random.default_rng(0).normal(size=(500, 4)) * [1.5, 1.0, 0.5, 1.0]
    steps = np.arange(500) % task.horizon + 1
    expected_reward, expected_end = task.reward(states, steps)
    reward, end = lookup(env_id).reward(task.observe(states), steps)
    np.testing.assert_allclose(reward, expected_reward, atol=1e-6)
    np.testing.assert_array_equal(end, expected_end)
    assert end.any() and not end.all()


def test_a_batch_larger_than_the_data_is_the_data_s_size():
    """A fit's batch is at most the training windows: a larger one only repeats windows (and held memory for them)."""
    weights = []
    for batch_size in (10**4, 10**5):
        torch.manual_seed(0)
        model = WorldModel(2, 1, (4,))
        settings = FitSettings(unfold=2, overshoot=2, learn_reward=False, batch_size=batch_size, max_updates=20)
        fit(model, EpisodeBuffer(linear_system_episodes(2, 20, seed=1)), settings)
        weights.append(torch.cat([p.detach().flatten() for p in model.parameters()]))
    assert torch.equal(*weights)
