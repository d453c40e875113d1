"""Recurrent policies (thesis 3.4, 3.15–3.21): PyTorch's own cells as reference, state isolation, memory."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv

from drrl.envs.batch import make_batch_env
from drrl.policies import ACCEPTED_FORMS, LSTM, ElmanRNN, linear, lstm, make_policy, rnn
from drrl.rollout import episode_seeds, evaluate
from drrl.search.pgpe import PGPE

P, B, STEPS = 3, 2, 6


def layer_weights(policy, params: torch.Tensor, candidate: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Candidate p's (fused matrix, bias) per layer, in float64."""
    weights = policy.unflatten(params)
    return [
        (weights[2 * i][candidate].double(), weights[2 * i + 1][candidate, 0].double())
        for i in range(len(policy.hidden))
    ]


def torch_rnn_cells(policy, params, candidate) -> list[torch.nn.RNNCell]:
    """nn.RNNCell per layer loaded with candidate p's weights: W = fused[:n]ᵀ, B = fused[n:]ᵀ, one bias."""
    cells = []
    for fan_in, width, (fused, bias) in zip(
        policy.inputs, policy.hidden, layer_weights(policy, params, candidate), strict=True
    ):
        cell = torch.nn.RNNCell(fan_in, width).double()
        cell.weight_ih.data, cell.weight_hh.data = fused[:fan_in].T.contiguous(), fused[fan_in:].T.contiguous()
        cell.bias_ih.data, cell.bias_hh.data = bias.clone(), torch.zeros(width, dtype=torch.float64)
        cells.append(cell)
    return cells


def torch_lstm_cells(policy, params, candidate) -> list[torch.nn.LSTMCell]:
    """nn.LSTMCell per layer loaded with candidate p's weights; our gate columns (i, f, o, g) → its rows
    (i, f, g, o)."""
    cells = []
    for fan_in, width, (fused, bias) in zip(
        policy.inputs, policy.hidden, layer_weights(policy, params, candidate), strict=True
    ):
        i, f, o, g = (torch.arange(width) + k * width for k in range(4))
        order = torch.cat([i, f, g, o])
        cell = torch.nn.LSTMCell(fan_in, width).double()
        cell.weight_ih.data = fused[:fan_in, order].T.contiguous()
        cell.weight_hh.data = fused[fan_in:, order].T.contiguous()
        cell.bias_ih.data, cell.bias_hh.data = bias[order].clone(), torch.zeros(4 * width, dtype=torch.float64)
        cells.append(cell)
    return cells


def read_out(policy, params, candidate, top: torch.Tensor) -> torch.Tensor:
    weights = policy.unflatten(params)
    return top @ weights[-2][candidate].double() + weights[-1][candidate, 0].double()


@pytest.mark.parametrize("hidden", [[5], [5, 3, 4]])
def test_elman_steps_equal_torch_rnn_cells_per_candidate(hidden):
    policy = rnn(4, 2, hidden)
    params = torch.randn(P, policy.num_params, generator=torch.Generator().manual_seed(0))
    observations = torch.randn(STEPS, P, B, 4, generator=torch.Generator().manual_seed(1))
    weights, state = policy.unflatten(params), policy.initial_state(P, B)
    references = [
        (torch_rnn_cells(policy, params, p), [torch.zeros(B, w, dtype=torch.float64) for w in hidden]) for p in range(P)
    ]
    for obs in observations:
        action, state = policy.act(weights, obs, state)
        for p, (cells, memory) in enumerate(references):
            x = obs[p].double()
            for layer, cell in enumerate(cells):
                x = memory[layer] = cell(x, memory[layer])
                torch.testing.assert_close(state[layer][0][p].double(), x, rtol=0, atol=1e-6)
            torch.testing.assert_close(action[p].double(), read_out(policy, params, p, x), rtol=0, atol=1e-6)


@pytest.mark.parametrize("hidden", [[5], [5, 3, 4]])
def test_lstm_steps_equal_torch_lstm_cells_per_candidate(hidden):
    policy = lstm(4, 2, hidden)
    params = torch.randn(P, policy.num_params, generator=torch.Generator().manual_seed(0))
    observations = torch.randn(STEPS, P, B, 4, generator=torch.Generator().manual_seed(1))
    weights, state = policy.unflatten(params), policy.initial_state(P, B)
    zeros = [torch.zeros(B, w, dtype=torch.float64) for w in hidden]
    references = [(torch_lstm_cells(policy, params, p), list(zip(zeros, zeros, strict=True))) for p in range(P)]
    for obs in observations:
        action, state = policy.act(weights, obs, state)
        for p, (cells, memory) in enumerate(references):
            x = obs[p].double()
            for layer, cell in enumerate(cells):
                memory[layer] = cell(x, memory[layer])
                x = memory[layer][0]
                for ours, theirs in zip(state[layer], memory[layer], strict=True):  # (h, c)
                    torch.testing.assert_close(ours[p].double(), theirs, rtol=0, atol=1e-6)
            torch.testing.assert_close(action[p].double(), read_out(policy, params, p, x), rtol=0, atol=1e-6)


def test_parameter_counts_and_state_shapes():
    assert rnn(4, 1, [16]).num_params == (4 + 16) * 16 + 16 + 16 + 1
    assert lstm(2, 1, [32, 32]).num_params == (2 + 32) * 128 + 128 + (32 + 32) * 128 + 128 + 32 + 1
    state = lstm(4, 1, [8, 3]).initial_state(5, 2)
    assert [[tuple(m.shape) for m in layer] for layer in state] == [[(5, 2, 8)] * 2, [(5, 2, 3)] * 2]
    assert all(not m.any() for layer in state for m in layer)
    assert [len(layer) for layer in rnn(4, 1, [8, 3]).initial_state(5, 2)] == [1, 1]


@pytest.mark.parametrize("make", [rnn, lstm])
def test_initial_center_acts_zero_and_scales_its_weights(make):
    policy = make(4, 1, [16, 8])
    center = policy.initial_center(torch.Generator().manual_seed(0))
    weights = policy.unflatten(center[None])
    action, _ = policy.act(weights, torch.randn(1, 7, 4), policy.initial_state(1, 7))
    assert not action.any()  # read-out 0: the centre acts 0
    for layer, (fan_in, width) in enumerate(zip(policy.inputs, policy.hidden, strict=True)):
        fused, bias = weights[2 * layer][0], weights[2 * layer + 1][0, 0]
        assert 0.7 < fused[:fan_in].std() * fan_in**0.5 < 1.3  # input rows ~ N(0, 1/n)
        for block in fused[fan_in:].split(width, dim=1):  # one w × w recurrent block per gate
            assert torch.linalg.eigvals(block).abs().max() == pytest.approx(0.5, rel=1e-5)
        expected_bias = torch.zeros(policy.gates * width)
        if make is lstm:
            expected_bias[width : 2 * width] = 1.0  # the forget gate's
        assert torch.equal(bias, expected_bias)


# ---------------------------------------------------------------------------------------------------- state


class LeakyAcrossRollouts(LSTM):
    """A broken LSTM that starts a rollout from the memory the previous rollout of the same size ended with."""

    def initial_state(self, population, batch, device="cpu"):
        last = getattr(self, "_last", None)
        if last is not None and last[0][0].shape[:2] == (population, batch):
            return last
        return super().initial_state(population, batch, device)

    def act(self, weights, obs, state):
        action, self._last = super().act(weights, obs, state)
        return action, self._last


class LeakyAcrossCandidates(ElmanRNN):
    """A broken Elman network whose candidates see each other's memory."""

    def act(self, weights, obs, state):
        action, state = super().act(weights, obs, state)
        return action, tuple((layer[0].roll(1, dims=0),) for layer in state)


class LeakyAcrossEpisodes(ElmanRNN):
    """A broken Elman network whose episodes (the slots of one candidate) see each other's memory."""

    def act(self, weights, obs, state):
        action, state = super().act(weights, obs, state)
        return action, tuple((layer[0].roll(1, dims=1),) for layer in state)


def one_episode(policy, params: torch.Tensor, episode_seed: int) -> float:
    """The return of one candidate (1, n) on one episode of a single env, from a fresh memory."""
    env = make_batch_env("cartpole-po", 1)
    weights, state = policy.unflatten(params), policy.initial_state(1, 1)
    obs, _ = env.reset(seed=[episode_seed])
    total, done = 0.0, False
    while not done:
        raw, state = policy.act(weights, torch.as_tensor(obs).view(1, 1, -1), state)
        obs, reward, terminated, truncated, _ = env.step(raw.view(1, 1).clamp(-1, 1).numpy())
        total += reward[0]
        done = terminated[0] or truncated[0]
    return total


def memory_is_isolated(policy) -> bool:
    """Whether P candidates × E episodes in one rollout equal the same rollout again, each candidate evaluated on its
    own, and each episode run on its own from a fresh memory."""
    population, episodes, seed = 4, 3, 11
    params = policy.initial_center(torch.Generator().manual_seed(2)) + 0.3 * torch.randn(
        population, policy.num_params, generator=torch.Generator().manual_seed(3)
    )
    env, env_one_candidate = (make_batch_env("cartpole-po", n) for n in (population * episodes, episodes))
    together = evaluate(policy, params, env, episodes, seed=seed).episode_returns
    again = evaluate(policy, params, env, episodes, seed=seed).episode_returns
    per_candidate = torch.cat(
        [
            evaluate(policy, params[p : p + 1], env_one_candidate, episodes, seed).episode_returns
            for p in range(population)
        ]
    )
    per_episode = torch.tensor(
        [
            [one_episode(policy, params[p : p + 1], s) for s in episode_seeds(seed, 1, episodes)]
            for p in range(population)
        ],
        dtype=torch.float64,
    )
    return (
        torch.equal(together, again)
        and torch.equal(together, per_candidate)
        and torch.allclose(together, per_episode, rtol=0, atol=1e-9)
    )


@pytest.mark.parametrize("policy", [rnn(2, 1, [6]), lstm(2, 1, [4, 5])])
def test_memory_starts_fresh_per_episode_and_stays_with_its_candidate(policy):
    assert memory_is_isolated(policy)


@pytest.mark.parametrize(
    "leaky", [LeakyAcrossRollouts(2, 1, [4]), LeakyAcrossCandidates(2, 1, [6]), LeakyAcrossEpisodes(2, 1, [6])]
)
def test_the_isolation_check_catches_leaking_memory(leaky):
    assert not memory_is_isolated(leaky)


# ---------------------------------------------------------------------------------------------------- memory task


class CueRecall(VectorEnv):
    """Recall a cue after a delay: t = 0 shows a cue c = ±1, the next ``delay`` steps show nothing, then a recall
    signal asks for it. The action at the recall step earns a·c (a clipped to [-1, 1]) and ends the episode; every
    other step earns 0. Observations (cue, recall). A feed-forward policy sees (0, 1) at the recall step whatever the
    cue, so over balanced cues it earns 0 on average; a policy that remembers earns 1."""

    def __init__(self, num_envs: int, delay: int = 5):
        self.num_envs, self.delay = num_envs, delay
        self.single_observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        self.cue = np.array([np.random.default_rng(s).choice([-1.0, 1.0]) for s in seed])
        self.t = 0
        return self._observe(), {}

    def step(self, actions):
        self.t += 1
        recalled = self.t == self.delay + 1  # the action just taken answered the recall signal
        reward = np.clip(actions[:, 0], -1, 1) * self.cue if recalled else np.zeros(self.num_envs)
        ended = np.full(self.num_envs, recalled)
        return self._observe(), reward, ended, np.zeros(self.num_envs, dtype=bool), {}

    def _observe(self):
        obs = np.zeros((self.num_envs, 2), dtype=np.float32)
        obs[:, 0] = self.cue if self.t == 0 else 0.0
        obs[:, 1] = float(self.t == self.delay)
        return obs


def search_cue_recall(policy, generations: int = 30, popsize: int = 16, episodes: int = 8) -> float:
    """PGPE on the cue task; the centre's mean return over 64 fresh episodes."""
    search = PGPE(
        policy.initial_center(torch.Generator().manual_seed(0)),
        popsize=popsize,
        sigma_init=0.5,
        center_lr=0.1,
        optimizer="adam",
        fitness_shaping="centered_ranks",
        seed=0,
    )
    env = CueRecall(popsize * episodes)
    for generation in range(generations):
        search.tell(evaluate(policy, search.ask(), env, episodes, seed=generation).returns.float())
    return evaluate(policy, search.center[None], CueRecall(64), 64, seed=10_000).returns.item()


def test_cue_recall_needs_memory_and_pgpe_finds_it():
    cues = CueRecall(64).reset(seed=np.random.default_rng(10_000).integers(2**63, size=64).tolist())[0][:, 0]
    chance = abs(cues.mean())  # the most a policy that ignores the cue can earn on these 64 episodes
    assert chance < 0.3
    assert search_cue_recall(rnn(2, 1, [2])) > 0.9
    assert search_cue_recall(linear(2, 1)) <= chance + 1e-6


# ---------------------------------------------------------------------------------------------------- specs


@pytest.mark.parametrize(
    "spec, kind, hidden", [("rnn:16", ElmanRNN, [16]), ("lstm:32,32", LSTM, [32, 32]), (" lstm:3 ", LSTM, [3])]
)
def test_specs_build_recurrent_policies(spec, kind, hidden):
    policy = make_policy(spec, 2, 1)
    assert type(policy) is kind and policy.hidden == hidden


@pytest.mark.parametrize("spec", ["gru:8", "rnn", "rnn:", "rnn:0", "lstm:-3", "lstm:8,0", "lstm:8,x", "lstm:8;8"])
def test_malformed_recurrent_specs_show_the_accepted_forms(spec):
    with pytest.raises(ValueError) as error:
        make_policy(spec, 2, 1)
    assert ACCEPTED_FORMS in str(error.value) and "rnn:W[,W...]" in str(error.value)


def test_a_recurrent_policy_needs_layers():
    with pytest.raises(ValueError, match="positive layer widths"):
        rnn(2, 1, [])
    with pytest.raises(ValueError, match="positive layer widths"):
        lstm(2, 1, [4, 0])
