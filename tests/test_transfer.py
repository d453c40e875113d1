"""Transfer (``start_from``): a run that starts from another run's policy and world model."""

import shutil

import pytest
import torch
from click.testing import CliRunner
from test_model_based import QUICK_MODEL

from drrl.cli import main
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.train import open_run, prepare, prepare_resume, train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

SOURCE = dict(popsize=8, episodes_per_candidate=2, budget=4, eval_episodes=5, model_based=QUICK_MODEL)


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A finished model-based cart-pole run: its folder, and its checkpoint."""
    out = tmp_path_factory.mktemp("source") / "run"
    train(TrainConfig.model_validate(SOURCE), out)
    return out, open_run(RunFolder(out))[1]


def test_a_run_starts_from_the_best_policy_and_the_world_model_of_another(source):
    out, checkpoint = source
    setup = prepare(TrainConfig.model_validate({**SOURCE, "seed": 5, "start_from": str(out)}))
    try:
        torch.testing.assert_close(setup.search.center, checkpoint["best_center"])
        for name, tensor in setup.world.model.state_dict().items():  # type: ignore[attr-defined]
            torch.testing.assert_close(tensor, checkpoint["world"]["model"][name])
    finally:
        setup.close()
    fresh = prepare(TrainConfig.model_validate({**SOURCE, "seed": 5}))
    try:
        assert not torch.equal(fresh.search.center, checkpoint["best_center"])
    finally:
        fresh.close()


def test_a_transferred_run_tries_the_policy_it_was_given_in_its_first_real_episodes(source, monkeypatch):
    """A fresh run's first real episodes are explorers only (its μ is uninformed); a transferred run's start with μ."""
    import drrl.training.model_based as model_based

    out, checkpoint = source
    tried, collect = [], model_based.collect

    def recorded(policy, params, *args):
        tried.append(params.clone())
        return collect(policy, params, *args)

    monkeypatch.setattr(model_based, "collect", recorded)
    train(TrainConfig.model_validate({**SOURCE, "seed": 5, "start_from": str(out)}))
    train(TrainConfig.model_validate({**SOURCE, "seed": 5}))
    transferred_first, fresh_first = tried[0], tried[len(tried) // 2]
    torch.testing.assert_close(transferred_first[0], checkpoint["best_center"])
    assert not torch.isclose(transferred_first[1:], checkpoint["best_center"]).all(dim=1).any()
    assert not (fresh_first == 0).all(dim=1).any()  # the fresh run's μ = 0 is not among its first episodes


def test_a_model_free_run_starts_from_a_model_based_runs_policy(source):
    out, checkpoint = source
    setup = prepare(TrainConfig.model_validate({"popsize": 8, "budget": 16, "start_from": str(out)}))
    try:
        torch.testing.assert_close(setup.search.center, checkpoint["best_center"])
    finally:
        setup.close()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"policy": "linear"}, "trained a linear:nobias policy, this run's is linear"),
        ({"env": "cartpole-po"}, "observation and action spaces"),
    ],
)
def test_another_policy_or_other_spaces_are_refused_before_any_work(source, change, message):
    out, _ = source
    with pytest.raises(ValueError, match=message):
        prepare(TrainConfig.model_validate({**SOURCE, **change, "start_from": str(out)}))


@pytest.mark.slow
def test_a_transferred_run_resumes_without_its_source_and_a_missing_source_is_refused(source, tmp_path):
    out, _ = source
    copy = tmp_path / "source"
    shutil.copytree(out, copy)
    settings = tmp_path / "settings.json"
    settings.write_text(TrainConfig.model_validate(SOURCE).model_dump_json(include={"model_based", "popsize"}))
    args = ["train", "cartpole", "--model-based", "--budget", "6", "--config", str(settings), "--quiet"]
    runner = CliRunner()
    first = runner.invoke(main, [*args, "--start-from", str(copy), "--out", str(tmp_path / "run")])
    assert first.exit_code == 0, first.output
    shutil.rmtree(copy)
    folder = RunFolder(tmp_path / "run")
    setup, counters = prepare_resume(folder)  # the checkpoint holds all it needs
    setup.close()
    folder.release()
    assert counters.real_episodes == 6
    missing = runner.invoke(main, [*args, "--start-from", str(copy), "--out", str(tmp_path / "other")])
    assert missing.exit_code == 2 and "does not exist" in missing.output
