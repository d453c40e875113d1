"""The one loop in both worlds: model-based runs resume exactly and run on Ray as they do locally; subscribers;
the searches behind one interface; the layers import downward only."""

import ast
import csv
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from drrl.envs.registry import lookup
from drrl.rollout.moments import Moments
from drrl.runs import RunFolder
from drrl.settings import ModelBasedSettings, TrainConfig
from drrl.streams import GENERATION_STEPS, Stream, derive_seed, imagined_seed
from drrl.training.loop import Counters, Subscriber, run, solved
from drrl.training.train import prepare, resume, subscribers, train

SOURCE = Path(__file__).parents[1] / "src" / "drrl"
TINY_MODEL = {
    "hidden": [8],
    "unfold": 2,
    "overshoot": 4,
    "generations_per_iteration": 3,
    "fit_updates": 40,
    "refit_updates": 20,
    "ensemble_size": 2,
}
MODEL_BASED = TrainConfig(
    model_based=TINY_MODEL, popsize=6, episodes_per_candidate=2, budget=8, eval_episodes=4, seed=3
)
TIMING = {"wall_time", "fit_time", "search_time"}


def metrics(out: Path) -> list[dict]:
    with (out / "metrics.csv").open(newline="") as handle:
        return [{key: value for key, value in row.items() if key not in TIMING} for row in csv.DictReader(handle)]


def tensors(state) -> dict:
    """Every tensor of a nested checkpoint state, by its path."""
    found = {}

    def walk(value, path):
        if isinstance(value, torch.Tensor):
            found[path] = value
        elif isinstance(value, dict):
            for key, item in value.items():
                walk(item, f"{path}/{key}")
        elif isinstance(value, list):
            for index, item in enumerate(value):
                walk(item, f"{path}/{index}")

    walk(state, "")
    return found


class StopAfter(Subscriber):
    """Ctrl-C just after the checkpoint of step ``iteration`` is written, as a person might press it."""

    def __init__(self, iteration: int):
        self.iteration = iteration

    def checkpoint(self, snapshot):
        if snapshot["iteration"] == self.iteration:
            raise KeyboardInterrupt


def test_model_based_defaults_merge_in_the_config_alone():
    config = TrainConfig(model_based={})
    assert (config.search.popsize, config.search.episodes_per_candidate, config.budget) == (20, 10, 20)
    assert TrainConfig(model_based={}, popsize=4).search.popsize == 4  # given settings win
    assert TrainConfig().search.popsize == 8  # model-free keeps its own


@pytest.mark.parametrize("stop_after", [1, 2])
@pytest.mark.slow
def test_a_stopped_model_based_run_resumes_to_the_uninterrupted_metrics_and_checkpoint(
    tmp_path, one_thread, stop_after
):
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    counters = train(MODEL_BASED, whole)
    assert counters.iteration == 4 and counters.real_episodes == 8 and counters.imagined_episodes > 0
    setup = prepare(MODEL_BASED)
    with pytest.raises(KeyboardInterrupt):
        run(setup, [*subscribers(RunFolder.create(stopped), progress=False), StopAfter(stop_after)])
    checkpoint = RunFolder(stopped).load_checkpoint()
    assert checkpoint["iteration"] == stop_after and checkpoint["world"]["buffer"]  # the model's data are kept
    resumed = resume(stopped)
    assert resumed.iteration == 4 and resumed.real_episodes == 8 and resumed.real_steps == counters.real_steps
    assert metrics(stopped) == metrics(whole)
    final, expected = tensors(RunFolder(stopped).load_checkpoint()), tensors(RunFolder(whole).load_checkpoint())
    assert final.keys() == expected.keys() and all(torch.equal(final[key], expected[key]) for key in expected)


NORMALISED = TrainConfig(
    env="Pendulum-v1",
    engine="gymnasium",
    search="pgpe",  # not Pendulum's own CMA-ES defaults
    sigma_init=0.025,
    episodes_per_candidate=1,
    policy="mlp:4",
    popsize=6,
    budget=36,
    eval_episodes=2,
    eval_share=1.0,
    checkpoint_every=2,
    seed=3,
)


@pytest.mark.parametrize(
    "config",
    [
        MODEL_BASED.model_copy(update={"budget": 6}),
        TrainConfig(search="cmaes", budget=48, eval_episodes=4, seed=2),
        NORMALISED,
    ],
    ids=["model-based PGPE", "model-free CMA-ES", "normalised observations"],
)
@pytest.mark.slow
def test_ray_equals_local_bit_for_bit(tmp_path, one_thread, config):
    pytest.importorskip("ray")
    train(config, tmp_path / "local")
    train(config, tmp_path / "ray", backend="ray", workers=2)
    assert metrics(tmp_path / "ray") == metrics(tmp_path / "local")
    assert len(metrics(tmp_path / "local")) == (3 if config.model_based else 6)
    on_ray, here = (tensors(RunFolder(tmp_path / name).load_checkpoint()) for name in ("ray", "local"))
    assert on_ray.keys() == here.keys() and all(torch.equal(on_ray[key], here[key]) for key in here)


def test_normalised_observations_resume_exactly_and_the_env_runs_the_folded_centre(tmp_path):
    whole = train(NORMALISED, tmp_path / "whole")
    checkpoint = RunFolder(tmp_path / "whole").load_checkpoint()
    moments = checkpoint["world"]["observation_moments"]
    assert int(moments["count"].sum()) == whole.real_steps  # every observation acted on in training, once
    assert RunFolder(tmp_path / "whole").read_config().world.observation_norm is True  # the resolved setting is kept
    setup = prepare(NORMALISED)
    with pytest.raises(KeyboardInterrupt):
        run(setup, [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(2)])
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")
    final, expected = tensors(RunFolder(tmp_path / "stopped").load_checkpoint()), tensors(checkpoint)
    assert all(torch.equal(final[key], expected[key]) for key in expected)
    searched = prepare(NORMALISED)  # the search's centre acts on normalised observations, the saved one on raw ones
    searched.search.load_state_dict(checkpoint["search"])
    mean, std = Moments.from_state_dict(moments).mean_std()
    assert not torch.allclose(checkpoint["center"], searched.search.center)
    assert torch.equal(checkpoint["center"], searched.policy.fold_input(searched.search.center[None], mean, std)[0])
    searched.close()


def test_model_free_cmaes_improves_the_cartpole_and_resumes_exactly(tmp_path):
    config = TrainConfig(search="cmaes", budget=160, eval_every=4, eval_share=1.0, seed=1)
    whole = train(config, tmp_path / "whole")
    measured = [row["center_return"] for row in whole.rows if row["center_return"] == row["center_return"]]
    assert measured[-1] > measured[0] + 50  # the thesis cart-pole's centre gets much better within 20 generations
    setup = prepare(config)
    with pytest.raises(KeyboardInterrupt):
        run(setup, [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(10)])
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")


def test_a_run_resumes_exactly_across_a_restart_with_fresh_observation_statistics(tmp_path):
    config = TrainConfig(restart_every=4, budget=80, observation_norm=True, checkpoint_every=1, seed=2)
    whole = train(config, tmp_path / "whole")
    assert whole.generations == 10
    with pytest.raises(KeyboardInterrupt):
        run(prepare(config), [*subscribers(RunFolder.create(tmp_path / "stopped"), progress=False), StopAfter(6)])
    resume(tmp_path / "stopped")
    assert metrics(tmp_path / "stopped") == metrics(tmp_path / "whole")
    written = metrics(tmp_path / "whole")
    moments = RunFolder(tmp_path / "whole").load_checkpoint()["world"]["observation_moments"]
    since_restart = int(written[-1]["real_steps"]) - int(written[7]["real_steps"])  # generations 9 and 10
    assert int(torch.as_tensor(moments["count"]).sum()) == since_restart


def test_the_loop_runs_torch_and_numpy_s_blas_on_one_thread_and_gives_their_threads_back():
    from threadpoolctl import threadpool_info

    seen = []

    class Threads(Subscriber):
        def row(self, setup, counters, row):
            blas = {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}
            seen.append((torch.get_num_threads(), blas))

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        run(prepare(TrainConfig(search="cmaes", budget=16)), [Threads()])
        assert seen == [(1, {1})] * 2 and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_tensorboard_logs_every_metric_against_real_episodes(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = TrainConfig(budget=24)
    run(prepare(config), subscribers(RunFolder.create(tmp_path / "run"), progress=False, tensorboard=True))
    events = EventAccumulator(str(tmp_path / "run" / "tensorboard"))
    events.Reload()
    assert {"center_return", "mean_return", "sigma_norm"} <= set(events.Tags()["scalars"])
    assert [event.step for event in events.Scalars("mean_return")] == [8, 16, 24]


# ------------------------------------------------------------------------------------------------ the layers

LAYER_RULES = {  # a module (or package) -> drrl modules it must not import, directly or lazily
    "training": ("drrl.cli", "drrl.compare", "drrl.video", "drrl.reference_ppo"),
    "training/model_based.py": ("drrl.training.model_free", "drrl.training.train"),
    "training/model_free.py": ("drrl.training.model_based", "drrl.training.action_space", "drrl.training.train"),
    "training/action_space.py": ("drrl.training.model_based", "drrl.training.train"),
    "training/loop.py": (
        "drrl.training.model_free",
        "drrl.training.model_based",
        "drrl.training.action_space",
        "drrl.training.train",
        "drrl.runs",
    ),
    "runs.py": ("drrl.training", "drrl.cli"),
    "settings": ("drrl.rollout", "drrl.training", "drrl.runs", "drrl.cli"),
    "models": ("drrl.envs", "drrl.search", "drrl.rollout", "drrl.training", "drrl.settings"),
    "policy_gradient": ("drrl.models", "drrl.training", "drrl.settings", "drrl.envs"),
    "search": ("drrl.envs", "drrl.models", "drrl.rollout", "drrl.policies", "drrl.settings"),
    "envs": ("drrl.models", "drrl.search", "drrl.rollout", "drrl.policies", "drrl.training", "drrl.settings"),
    "rollout": ("drrl.models", "drrl.search", "drrl.training", "drrl.settings"),
    "streams.py": ("drrl",),  # the lowest: numpy only
}


def drrl_imports(file: Path) -> set[str]:
    """The drrl modules ``file`` imports anywhere in it."""
    found = set()
    for node in ast.walk(ast.parse(file.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("drrl"):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("drrl"))
    return found


def module_name(file: Path) -> str:
    parts = file.relative_to(SOURCE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@pytest.mark.parametrize("where", sorted(LAYER_RULES))
def test_layers_import_downward_only(where):
    files = [SOURCE / where] if where.endswith(".py") else sorted((SOURCE / where).rglob("*.py"))
    for file in files:
        bad = [name for name in drrl_imports(file) if name.startswith(LAYER_RULES[where])]
        assert not bad, f"{file.relative_to(SOURCE)} imports {bad}"


def test_the_package_root_keeps_a_few_entry_modules_and_subpackages_group_the_rest():
    modules = sorted(file.name for file in SOURCE.glob("*.py") if file.name != "__init__.py")
    assert len(modules) <= 6, modules


def test_the_architecture_page_has_a_row_for_every_module_and_none_for_a_module_that_is_gone():
    rows = re.findall(r"^\| `([\w/.]+)` \|", (SOURCE.parents[1] / "docs" / "architecture.md").read_text(), re.M)
    described = {row for row in rows if row.endswith(".py")}
    folders = tuple(row for row in rows if row.endswith("/"))  # a package described as a whole (envs/compiled/)
    modules = {
        str(file.relative_to(SOURCE))
        for file in SOURCE.rglob("*.py")
        if not str(file.relative_to(SOURCE)).startswith(folders)
    }
    undocumented = {module for module in modules - described if not module.endswith("__init__.py")}
    assert not undocumented, f"docs/architecture.md has no row for {sorted(undocumented)}"
    assert not described - modules, f"docs/architecture.md describes {sorted(described - modules)}, which do not exist"
    assert all((SOURCE / folder).is_dir() for folder in folders)


def test_no_import_circle():
    modules = {module_name(file): file for file in SOURCE.rglob("*.py")}
    graph = {
        name: {
            imported
            for imported in drrl_imports(file)
            if imported in modules and imported != name and not name.startswith(imported + ".")
        }  # a module's own package is loaded first anyway
        for name, file in modules.items()
    }
    done, path = set(), []

    def visit(name):
        if name in path:
            raise AssertionError(f"import circle: {' -> '.join([*path[path.index(name) :], name])}")
        if name in done:
            return
        path.append(name)
        for imported in graph[name]:
            visit(imported)
        path.pop()
        done.add(name)

    for name in graph:
        visit(name)


def test_the_model_guard_warns_when_the_model_promises_far_more_than_reality_gives():
    from drrl.training.loop import Counters
    from drrl.training.subscribers import ModelGuard

    said = []
    guard = ModelGuard(say=said.append)
    counters = Counters(iteration=3)
    guard.row(None, counters, {"imagined_center_return": 654.0, "center_return": 4.6})  # a model being exploited
    guard.row(None, counters, {"imagined_center_return": -184.4, "center_return": -322.7})  # a pessimistic one
    guard.row(None, counters, {"imagined_center_return": -40.0, "center_return": -45.0})  # one that is right
    guard.row(None, counters, {"center_return": -45.0})  # a model-free row
    assert guard.warned == 1 and "promised the centre 654.0, reality gave 4.6" in said[0]
    assert "--ensemble 5" in said[0] and "disagreement penalty" in said[0]
    guard.row(None, Counters(iteration=4), {"imagined_center_return": 600.0, "center_return": 2.0})
    assert said[1].endswith("iteration 4: the world model promised the centre 600.0, reality gave 2.0; exploited again")
    five = SimpleNamespace(config=SimpleNamespace(model_based=ModelBasedSettings(ensemble_size=5)))
    ModelGuard(say=said.append).row(five, counters, {"imagined_center_return": 654.0, "center_return": 4.6})
    assert "--ensemble" not in said[2] and "disagreement penalty" in said[2]  # only what the run does not do
    linear = SimpleNamespace(config=SimpleNamespace(model_based=ModelBasedSettings(model_kind="linear")))
    ModelGuard(say=said.append).row(linear, counters, {"imagined_center_return": 654.0, "center_return": 4.6})
    assert "--model-kind rnn or lstm" in said[3] and "--model-hidden" not in said[3]  # a linear model has no width


@pytest.mark.slow
def test_measuring_takes_about_a_quarter_of_the_env_steps_by_default():
    """50 measuring episodes after each generation of 8 would cost six times the training; by default the loop
    measures only while measuring stays within a quarter of the steps, and always after the last generation."""
    counters = train(TrainConfig(budget=400, seed=0))
    measured = [row["generation"] for row in counters.rows if row["center_return"] == row["center_return"]]
    assert 1 < len(measured) < 10 and measured[-1] == 50
    last = counters.eval_steps / len(measured) * 2  # generous: the last measurement is of the longest episodes
    assert counters.eval_steps - last <= 0.25 * (counters.real_steps + counters.eval_steps)
    every = train(TrainConfig(budget=400, seed=0, eval_share=1.0))
    assert every.eval_episodes == 50 * 50 and every.real_steps == counters.real_steps  # measuring changes no training


@pytest.mark.parametrize("search", ["pgpe", "reinforce"])
def test_the_search_is_told_returns_less_the_reward_shift_and_the_metrics_keep_the_env_s_own(search):
    """CartPole-v1 pays 1 a step, so with a shift of 1 every episode is worth 0 to the search: μ does not move
    (PGPE's tied generations keep it, REINFORCE's gradient is 0). Without the shift it moves."""
    centres = []
    for shift in (1.0, 0.0):
        config = TrainConfig(env="CartPole-v1", search=search, budget=64, reward_shift=shift, seed=2)
        setup = prepare(config)
        start = setup.search.center.clone()
        counters = run(setup, [])
        centres.append((start, setup.search.center))
        returns = [row["mean_return"] for row in counters.rows]
        assert min(returns) >= 8  # the env's own returns: every episode lasts at least 8 steps
    (start, shifted), (other_start, unshifted) = centres
    assert torch.equal(start, shifted) and not torch.equal(other_start, unshifted)


def test_solved_in_a_row_counts_measured_centres_only_and_needs_the_last_step_measured():
    setup = SimpleNamespace(
        entry=lookup("cartpole"), config=TrainConfig(env="cartpole", stop_when_solved=True, solved_in_a_row=2)
    )
    yes, no = {"balanced": 1.0, "near_optimal": 1.0}, {"balanced": 1.0, "near_optimal": 0.0}
    unmeasured = {"balanced": float("nan"), "near_optimal": float("nan")}

    def done(*rows):
        return solved(setup, Counters(iteration=len(rows), rows=list(rows)))

    assert done(yes, unmeasured, unmeasured, yes)
    assert not done(no, unmeasured, yes)
    assert not done(yes)
    assert not done(yes, yes, unmeasured)


# ------------------------------------------------------------------------------------------------ the random streams


def test_every_stream_keeps_its_number_and_only_the_two_old_pairs_share_one():
    """A stream's number is part of every seed a run draws: they stay as they were, and only the two pairs that
    never meet in one run (a model-based world has no demonstrations or restarts) share a number."""
    numbers = {name: int(stream) for name, stream in Stream.__members__.items()}
    assert numbers == {
        "TRAINING": 0,
        "MEASURING": 1,
        "DEMONSTRATING": 2,
        "RESTARTING": 3,
        "IMAGINING": 2,
        "FITTING": 3,
        "EXPLORING": 4,
        "SEEING": 5,
        "EVALUATING": 6,
        "BENCHMARKING": 7,
    }
    shared = {name for name, stream in Stream.__members__.items() if stream.name != name}
    assert shared == {"IMAGINING", "FITTING"}
    assert not {"demonstrations", "restart_every"} & set(ModelBasedSettings.model_fields)
    for model_free_only in ({"demonstrations": 4}, {"restart_every": 5}):
        with pytest.raises(ValueError, match=f"{next(iter(model_free_only))}"):
            TrainConfig.model_validate({"model_based": {}, **model_free_only})


def test_an_in_model_generation_has_steps_of_the_imagining_stream_no_other_use_can_take():
    assert imagined_seed(3, 2, 7) == int(np.random.SeedSequence([3, 2_000_007, 2]).generate_state(1)[0])
    assert derive_seed(3, 2, Stream.IMAGINING) == int(np.random.SeedSequence([3, 2, 2]).generate_state(1)[0])
    with pytest.raises(ValueError, match="imagined_seed"):
        derive_seed(3, 2_000_007, Stream.IMAGINING)
    with pytest.raises(ValueError, match="generation"):
        imagined_seed(3, 2, GENERATION_STEPS)
