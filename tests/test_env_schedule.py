"""A curriculum on one env option: the schedule's values, the training env that follows it while measuring does not,
exact resume, and clear refusals."""

import math

import pytest
from click.testing import CliRunner
from pydantic import ValidationError
from test_loop import StopAfter, metrics

from drrl.cli import main
from drrl.envs.batch import make_batch_env
from drrl.runs import RunFolder
from drrl.settings import EnvSchedule, TrainConfig, describe_errors
from drrl.training.loop import run
from drrl.training.train import prepare, resume, subscribers

# Pendulum's gravity g (Gymnasium's default 10) from 20 down to 5 over the whole budget of 3 generations
SCHEDULED = TrainConfig(
    env="Pendulum-v1",
    engine="gymnasium",
    search="pgpe",  # not Pendulum's own CMA-ES defaults: small and quick
    policy="linear",
    sigma_init=0.025,
    episodes_per_candidate=1,
    popsize=4,
    budget=12,
    max_steps=10,
    eval_episodes=2,
    checkpoint_every=1,
    env_schedule={"option": "g", "start": 20.0, "end": 5.0, "share": 1.0},
)


def test_the_schedule_moves_geometrically_over_its_share_then_holds():
    schedule = EnvSchedule(option="tolerance", start=0.5, end=0.05, share=0.5)
    assert schedule.value(0.0) == 0.5
    assert schedule.value(0.25) == pytest.approx(math.sqrt(0.5 * 0.05))
    assert schedule.value(0.5) == pytest.approx(0.05) and schedule.value(1.0) == pytest.approx(0.05)


def test_training_follows_the_schedule_and_measuring_sees_the_registered_env():
    setup = prepare(SCHEDULED)
    try:
        counters = run(setup)
        expected = [SCHEDULED.world.env_schedule.value(done / 12) for done in (0, 4, 8)]
        assert [row["g"] for row in counters.rows] == pytest.approx(expected)
        assert [env.unwrapped.g for env in setup.world.backend.env.envs] == pytest.approx([expected[-1]] * 4)
        assert [env.unwrapped.g for env in setup.eval_env.envs] == [10.0, 10.0]
    finally:
        setup.close()


def test_a_scheduled_run_resumes_exactly(tmp_path):
    whole = prepare(SCHEDULED)
    run(whole, subscribers(RunFolder.create(tmp_path / "whole"), progress=False))
    stopped = prepare(SCHEDULED)
    with pytest.raises(KeyboardInterrupt):
        run(stopped, [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(1)])
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")
    assert [float(row["g"]) for row in metrics(tmp_path / "whole")] == pytest.approx(
        [SCHEDULED.world.env_schedule.value(done / 12) for done in (0, 4, 8)]
    )


def test_options_reach_the_env_and_an_unknown_one_is_refused_before_any_work(tmp_path):
    env = make_batch_env("Pendulum-v1", 2, "gymnasium", {"g": 2.0})
    assert [sub.unwrapped.g for sub in env.envs] == [2.0, 2.0]
    env.close()
    with pytest.raises(ValueError, match=r"Pendulum-v1 cannot be made with options \{'gravity': 2.0\}"):
        make_batch_env("Pendulum-v1", 2, "gymnasium", {"gravity": 2.0})
    settings = tmp_path / "settings.toml"
    settings.write_text('env = "Pendulum-v1"\n[env_schedule]\noption = "gravity"\nstart = 20.0\nend = 5.0\n')
    result = CliRunner().invoke(main, ["train", "--config", str(settings), "--out", str(tmp_path / "run")])
    assert result.exit_code == 2 and "cannot be made with options {'gravity': 20.0}" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()


def test_a_schedule_is_for_model_free_runs_and_moves_between_positive_values():
    with pytest.raises(ValidationError) as error:
        TrainConfig(model_based={}, env_schedule={"option": "tolerance", "start": 0.5, "end": 0.05})
    assert "env_schedule: a setting of model-free runs, not of model-based ones" in describe_errors(error.value)
    with pytest.raises(ValidationError, match="greater than 0"):
        TrainConfig(env_schedule={"option": "tolerance", "start": 0.0, "end": 0.05})


def test_an_adaptive_schedule_steps_only_after_generations_that_earned_it():
    schedule = EnvSchedule(option="g", start=20.0, end=5.0, advance_at=-1e9, steps=4)
    assert schedule.value(0.9, stage=2) == pytest.approx(20.0 * (5.0 / 20.0) ** 0.5)  # the budget does not count
    assert schedule.value(0.0, stage=9) == pytest.approx(5.0)
    for advance_at, stages in ((-1e9, (0, 1, 2)), (1e9, (0, 0, 0))):  # every generation earns a step / none does
        adaptive = {"option": "g", "start": 20.0, "end": 5.0, "advance_at": advance_at, "steps": 4}
        setup = prepare(SCHEDULED.updated(env_schedule=adaptive))
        try:
            rows = run(setup).rows
        finally:
            setup.close()
        assert [row["g"] for row in rows] == pytest.approx([20.0 * 0.25 ** (stage / 4) for stage in stages])


def test_an_adaptive_schedule_resumes_exactly(tmp_path):
    config = SCHEDULED.updated(env_schedule=dict(option="g", start=20.0, end=5.0, advance_at=-1e9, steps=4))
    run(prepare(config), subscribers(RunFolder.create(tmp_path / "whole"), progress=False))
    with pytest.raises(KeyboardInterrupt):
        run(prepare(config), [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(2)])
    assert RunFolder(tmp_path / "stopped").load_checkpoint()["world"]["schedule_stage"] == 2
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")
