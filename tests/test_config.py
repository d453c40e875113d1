from pathlib import Path

import pytest
from pydantic import ValidationError

from drrl.settings import TrainConfig, describe_errors, load_config_file


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"sampler": "genetic"}, "'genetic' is not one of: single, symmetric, supersymmetric"),
        ({"optimizer": "lbfgs"}, "'lbfgs' is not one of: sgd, adam, clipup"),
        (
            {"sigma_init": 0},
            "sigma_init: Input should be greater than 0 (got 0) — sigma_init: initial σ of every parameter",
        ),
        ({"popsize": 7}, "symmetric sampling needs an even popsize"),
        ({"sampler": "supersymmetric", "popsize": 10}, "supersymmetric sampling needs a popsize divisible by 4"),
        (
            {"popsize": "eight"},
            "popsize: must be a number, not text (got 'eight') — popsize: candidates per generation",
        ),
        ({"search": "cmaes", "sampler": "single"}, "a setting of the pgpe search, not of cmaes"),
        ({"model_based": {}, "observation_norm": True}, "a setting of model-free runs, not of model-based ones"),
        ({"search": "enac", "demonstrations": 4}, "a setting of model-free runs, not of action-space ones"),
        (
            {"budget": 5, "popsize": 6},
            "budget of 5 real episodes is smaller than one generation (6 candidates × 1 episode(s) each)",
        ),
        ({"popsiz": 10}, "popsiz: not a setting (did you mean popsize?)"),
    ],
)
def test_invalid_settings_name_the_field_and_what_is_allowed(settings, message):
    with pytest.raises(ValidationError) as error:
        TrainConfig.model_validate(settings)
    assert message in describe_errors(error.value)


def test_config_files_in_toml_and_json(tmp_path):
    (tmp_path / "a.toml").write_text('policy = "mlp:8"\nbudget = 200\n')
    (tmp_path / "b.json").write_text('{"sampler": "reinforce"}')
    assert load_config_file(tmp_path / "a.toml") == {"policy": "mlp:8", "budget": 200}
    assert load_config_file(tmp_path / "b.json") == {"sampler": "reinforce"}
    (tmp_path / "c.toml").write_text("policy = ")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_config_file(tmp_path / "c.toml")
    with pytest.raises(ValueError, match="cannot read config file"):
        load_config_file(tmp_path / "missing.toml")


def test_generations_fill_the_budget_with_whole_generations():
    config = TrainConfig(popsize=10, episodes_per_candidate=2, budget=95)
    assert config.episodes_per_generation == 20 and config.total_generations == 4


def test_the_config_files_the_docs_point_to_are_valid():
    paths = sorted((Path(__file__).parents[1] / "configs").glob("*.toml"))
    assert paths, "configs/ holds no config files"
    for path in paths:
        TrainConfig.model_validate(load_config_file(path))  # raises if invalid


def test_gymnasiums_envs_start_from_their_own_model_free_defaults_and_given_settings_win():
    hopper = TrainConfig(env="Hopper-v5")
    assert (hopper.policy, hopper.search.sigma_init, hopper.search.popsize, hopper.search.fitness_shaping) == (
        "linear",
        0.025,
        16,
        "centered_ranks",
    )
    assert TrainConfig(env="Hopper-v5", sigma_init=0.1).search.sigma_init == 0.1
    for own in ("cartpole", "drrl/CartPole-v0", "baxter-reach-right"):
        assert TrainConfig(env=own).model_dump(exclude={"env"}) == TrainConfig().model_dump(exclude={"env"})
    assert TrainConfig(env="Hopper-v5", model_based={}).policy == TrainConfig().policy  # model-based: its own


def test_hopper_s_search_is_not_told_of_its_survival_bonus_and_other_envs_are_told_all():
    assert TrainConfig(env="Hopper-v5").world.reward_shift == 1.0  # Hopper-v5 pays 1 a step for staying up
    assert TrainConfig(env="Hopper-v5", reward_shift=0).world.reward_shift == 0.0  # given wins
    assert TrainConfig(env="Walker2d-v5").world.reward_shift == TrainConfig().world.reward_shift == 0.0


def test_reacher_s_model_free_run_searches_a_tanh_network_on_many_episodes_and_its_model_based_run_its_own():
    reacher = TrainConfig(env="Reacher-v5")
    assert (reacher.policy, reacher.search.popsize, reacher.search.episodes_per_candidate, reacher.budget) == (
        "mlp:32",
        32,
        8,
        409600,
    )
    measured = (reacher.measuring.eval_episodes, reacher.world.eval_share, reacher.search.sigma_init)
    assert measured == (200, 0.1, 0.025)  # the rest: Gymnasium's
    assert TrainConfig(env="Reacher-v5", budget=3200).budget == 3200  # given wins
    model_based = TrainConfig(env="Reacher-v5", model_based={})
    assert (model_based.budget, model_based.measuring.eval_episodes) == (160, TrainConfig().measuring.eval_episodes)


def test_pendulum_s_model_based_run_starts_from_its_own_settings():
    model_based = TrainConfig(env="Pendulum-v1", model_based={})
    assert (model_based.search.name, model_based.policy, model_based.search.sigma_init, model_based.budget) == (
        "cmaes",
        "mlp:16",
        0.5,
        30,
    )
    assert model_based.model_based is not None and model_based.model_based.generations_per_iteration == 120
    assert model_based.model_based.mirror_episodes
    assert (
        TrainConfig(
            env="Pendulum-v1", model_based={"generations_per_iteration": 10}
        ).model_based.generations_per_iteration
        == 10
    )  # merged
    assert TrainConfig(env="Acrobot-v1", model_based={}).policy == TrainConfig(model_based={}).policy  # none of its own


def test_the_swing_up_starts_from_its_own_settings_model_free_and_model_based():
    swing_up = TrainConfig(env="cartpole-swingup")
    shown = (swing_up.policy, swing_up.search.popsize, swing_up.budget, swing_up.search.sigma_init)
    assert shown == ("mlp:16", 200, 40_000, 0.25)
    assert TrainConfig(env="cartpole-swingup", popsize=100).search.popsize == 100
    model_based = TrainConfig(env="cartpole-swingup", model_based={})
    assert (model_based.policy, model_based.budget, model_based.search.episodes_per_candidate) == ("mlp:16", 30, 1)
    assert model_based.model_based is not None and model_based.model_based.model_kind == "polynomial"
    assert model_based.model_based.episodes_per_iteration == 1  # a new model and centre after every real episode
    assert model_based.model_based.mirror_episodes and model_based.model_based.keep_unless_improved
    smaller = TrainConfig(env="cartpole-swingup", model_based={"ensemble_size": 3})
    assert smaller.model_based is not None
    assert (smaller.model_based.ensemble_size, smaller.model_based.model_kind) == (3, "polynomial")  # merged
    pixels = TrainConfig(env="cartpole-swingup-pixels", model_based={}).model_based
    assert pixels is not None and (pixels.model_kind, pixels.mirror_episodes) == ("lstm", False)  # as measured
    assert (pixels.exploration_bonus, pixels.episodes_per_iteration) == (3.0, 4)
