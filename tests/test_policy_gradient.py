"""Action-space policy gradients (thesis 2.1.4, 2.2.2): REINFORCE with a baseline and eNAC against gradients worked
out by hand on a Gaussian bandit; their episodes counted and replayed exactly; training on the cart-pole through
the one loop, with an exact resume and clear refusals."""

import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from test_loop import StopAfter, metrics, tensors

from drrl.cli import main
from drrl.envs.batch import make_batch_env
from drrl.policies import make_policy
from drrl.policy_gradient import ENAC, Episodes, Reinforce, collect, log_probs
from drrl.rollout import Evaluation, evaluate
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.loop import run
from drrl.training.train import prepare, resume, subscribers, train


def bandit_episodes(theta: float, sigma: float, target: float, batch: int, seed: int = 0) -> Episodes:
    """One-step episodes of a ~ N(θ, σ²) (a linear policy's output θ·1) with reward −(a − target)²."""
    generator = torch.Generator().manual_seed(seed)
    actions = theta + sigma * torch.randn(1, batch, 1, generator=generator)
    rewards = -((actions[..., 0] - target) ** 2).double()
    evaluation = Evaluation(
        rewards.reshape(1, batch), torch.ones(1, batch, dtype=torch.bool), torch.ones(1, batch, dtype=torch.int64)
    )
    return Episodes(torch.ones(1, batch, 1), actions, rewards, torch.ones(1, batch, dtype=torch.bool), evaluation)


@pytest.mark.parametrize("method", [Reinforce, ENAC])
def test_the_gradients_match_the_gaussian_bandit_s_own(method):
    """J(θ, σ) = −(θ − c)² − σ²: ∇_θ J = −2(θ − c), ∇_{log σ} J = −2σ². The Fisher information of N(θ, σ²) in
    (θ, log σ) is diag(1/σ², 2), so the natural gradient (2.6) is (−2σ²(θ − c), −σ²)."""
    theta, sigma, target = 0.3, 0.5, 1.0
    policy = make_policy("linear:nobias", 1, 1)
    learner = method(policy, torch.tensor([theta]), discrete=False, sigma_init=sigma, lr=0.1)
    grad_theta, grad_log_std = learner.ascent(bandit_episodes(theta, sigma, target, 200_000))
    if method is Reinforce:
        expected = (-2 * (theta - target), -2 * sigma**2)
    else:
        expected = (-2 * sigma**2 * (theta - target), -(sigma**2))
    assert float(grad_theta) == pytest.approx(expected[0], rel=0.03)
    assert float(grad_log_std) == pytest.approx(expected[1], rel=0.03)


def test_a_step_follows_the_gradient_and_counts_the_update():
    policy = make_policy("linear:nobias", 1, 1)
    learner = Reinforce(policy, torch.tensor([0.0]), discrete=False, sigma_init=0.5, lr=0.05, optimizer="sgd")
    learner.improve(bandit_episodes(0.0, 0.5, 1.0, 50_000))
    assert float(learner.center) == pytest.approx(0.05 * 2.0, rel=0.05)  # θ + α · 2(c − θ)
    assert float(learner.spread) < 0.5 and learner.generation == 1


def test_collect_counts_as_evaluate_does_and_keeps_every_step():
    env = make_batch_env("cartpole", 6, "native")
    policy = make_policy("linear:nobias", 4, 1)
    learner = Reinforce(policy, torch.tensor([0.5, 0.5, 2.0, 0.5]), discrete=False, sigma_init=0.3, lr=0.1)
    episodes = collect(learner.explorer(), learner.center, env, seed=7)
    lengths = episodes.alive.sum(0)
    assert int(lengths.sum()) == episodes.evaluation.steps and episodes.evaluation.episodes == 6
    assert torch.allclose(episodes.rewards.sum(0), episodes.evaluation.episode_returns[0])
    assert (episodes.rewards[~episodes.alive] == 0).all()
    assert not (episodes.actions[:, :, 0] == episodes.actions[:, :1, 0]).all()  # every episode draws its own noise
    again = evaluate(policy, learner.center[None], env, 6, seed=7)  # the same starts: only the noise differs
    assert not torch.equal(again.episode_returns, episodes.evaluation.episode_returns)
    env.close()


def test_a_recurrent_policy_s_replay_gives_one_log_probability_per_step_whatever_the_split():
    env = make_batch_env("cartpole-po", 4, "native")
    policy = make_policy("lstm:4", 2, 1)
    center = policy.initial_center(torch.Generator().manual_seed(0))
    learner = ENAC(policy, center, discrete=False, sigma_init=0.4, lr=0.1)
    episodes = collect(learner.explorer(), center, env, seed=1)
    together = log_probs(policy, center[None], learner.log_std.detach()[None], episodes, False)[:, 0]
    apart = log_probs(policy, center.expand(4, -1), learner.log_std.detach().expand(4, -1), episodes, False)[..., 0]
    assert torch.allclose(together, apart, atol=1e-5)
    # the first step's action is the policy's mean output plus noise of std σ: its log-density by hand
    mean = policy.act(policy.unflatten(center[None]), episodes.observations[:1], policy.initial_state(1, 4))[0][0]
    noise = (episodes.actions[0] - mean) / 0.4
    by_hand = (-0.5 * noise**2 - math.log(0.4) - 0.5 * math.log(2 * math.pi)).sum(-1)
    assert torch.allclose(together[0], by_hand, atol=1e-5)
    env.close()


def test_discrete_actions_are_drawn_from_the_softmax():
    env = make_batch_env("CartPole-v1", 400, "gymnasium")
    policy = make_policy("linear:nobias", 4, 2)
    learner = Reinforce(policy, torch.zeros(8), discrete=True, sigma_init=1.0, lr=0.1)
    episodes = collect(learner.explorer(), learner.center, env, seed=0, max_steps=1)
    assert learner.spread.numel() == 0
    assert episodes.actions.sum(-1).eq(1).all()  # one-hot choices
    assert float(episodes.actions[0, :, 0].mean()) == pytest.approx(0.5, abs=0.08)  # zero logits: a fair coin
    env.close()


@pytest.mark.parametrize("method", ["reinforce", "enac"])
@pytest.mark.slow
def test_training_improves_the_thesis_cart_pole_and_resumes_exactly(tmp_path, method):
    config = TrainConfig(search=method, budget=480, seed=1, eval_every=5, eval_share=1.0)
    whole = train(config, tmp_path / "whole")
    measured = [row["center_return"] for row in whole.rows if row["center_return"] == row["center_return"]]
    assert max(measured) > measured[0] + 50
    assert whole.real_episodes == 480 and whole.eval_episodes == 50 * len(measured)
    setup = prepare(config)
    with pytest.raises(KeyboardInterrupt):
        run(setup, [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(10)])
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")
    final = tensors(RunFolder(tmp_path / "stopped").load_checkpoint())
    expected = tensors(RunFolder(tmp_path / "whole").load_checkpoint())
    assert final.keys() == expected.keys() and all(torch.equal(final[key], expected[key]) for key in expected)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--model-based"], "search: 'enac' is not one of: 'pgpe', 'cmaes', 'sep-cmaes'"),
        (["--observation-norm"], "observation_norm: a setting of model-free runs, not of action-space ones"),
        (["--backend", "ray"], "use the local backend"),
    ],
)
def test_what_an_action_space_run_cannot_do_is_refused_in_one_line(tmp_path, args, said):
    result = CliRunner().invoke(main, ["train", "cartpole", "--search", "enac", "--out", str(tmp_path / "r"), *args])
    assert result.exit_code == 2 and said in result.output and "Traceback" not in result.output
    assert not (tmp_path / "r").exists()


def test_eval_runs_an_action_space_run_s_best_centre(tmp_path):
    runner = CliRunner()
    out = tmp_path / "run"
    trained = runner.invoke(main, ["train", "cartpole", "--search", "reinforce", "--budget", "64", "--out", str(out)])
    assert trained.exit_code == 0, trained.output
    evaluated = runner.invoke(main, ["eval", str(out), "--episodes", "5"])
    assert evaluated.exit_code == 0 and "balanced" in evaluated.output
    assert np.isfinite(RunFolder(out).load_checkpoint()["best_center_return"])
