"""The settings as parts: one description per setting, used everywhere; presets in one place; the flat form and its
sources; settings from the command line; run folders an older drrl wrote."""

import ast
import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from pydantic import ValidationError

from drrl.cli import main
from drrl.cli.settings import FLAGS, reference_table
from drrl.runs import RunFolder
from drrl.settings import TrainConfig, describe_errors
from drrl.settings.flat import FLAT, SEARCHES, WORLDS, flattened, nested
from drrl.settings.presets import PRESETS, TASKS, not_learned
from drrl.training.train import train

SOURCE = Path(__file__).parents[1] / "src" / "drrl"
BAD_VALUES = {int: -7, float: -1e9, bool: "maybe", str: "no-such-choice"}


def words(text: str) -> str:
    return " ".join(text.split())


def test_every_setting_has_one_description_in_every_part_that_has_it():
    for name, setting in FLAT.items():
        assert setting.field.description, f"{name} has no description"
        parts = [*SEARCHES.values(), *WORLDS.values()]
        field = name.removeprefix("model_based.")
        described = {part.model_fields[field].description for part in parts if field in part.model_fields}
        assert len(described) <= 1, f"{name} is described {len(described)} ways: {described}"


def test_help_the_reference_and_errors_use_each_setting_s_description():
    helped = words(CliRunner().invoke(main, ["train", "--help"], terminal_width=1000).output)
    reference = reference_table()
    for name, flag in FLAGS.items():
        description = FLAT[name].field.description
        assert words(description) in helped, f"--help lacks {flag}'s description"
        assert f"| `{name}` | `{flag}` |" in reference and description in reference
    for name in ("popsize", "sigma_init", "eval_episodes", "restart_every", "budget"):
        with pytest.raises(ValidationError) as error:
            TrainConfig.model_validate({name: -7})
        assert f"{name}: {FLAT[name].field.description}" in describe_errors(error.value)


def test_model_based_settings_are_described_and_bad_values_say_so():
    with pytest.raises(ValidationError) as error:
        TrainConfig(model_based={"ensemble_size": 0})
    message = describe_errors(error.value)
    assert message.startswith("model_based.ensemble_size: Input should be greater than or equal to 1 (got 0)")
    assert FLAT["model_based.ensemble_size"].field.description in message


def test_no_module_but_the_presets_defines_a_task_s_settings():
    found = []
    for path in SOURCE.rglob("*.py"):
        if path == SOURCE / "settings" / "presets.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and isinstance(node.value, (ast.Dict, ast.Call)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = [target.id for target in targets if isinstance(target, ast.Name)]
                found += [
                    f"{path.relative_to(SOURCE)}: {name}" for name in names if re.search(r"_(DEFAULTS|SETTINGS)$", name)
                ]
    assert not found, found


def test_every_task_preset_names_a_registered_env_and_presets_validate():
    from drrl.envs.registry import lookup

    for env_id, kinds in TASKS.items():
        assert lookup(env_id).env_id == env_id
        for kind, preset in kinds.items():
            assert preset in PRESETS
            world = {"model_based": {}} if kind == "model-based" else {}
            config = TrainConfig.model_validate({"env": env_id, **world})
            # a preset stops a run at its verdict only where the task has one (a dense reward's has none)
            assert not config.measuring.stop_when_solved or lookup(env_id).criteria(), (env_id, kind)


def test_a_preset_s_settings_a_chosen_search_does_not_have_are_left_out_but_given_ones_are_refused():
    cmaes = TrainConfig(env="cartpole-swingup", search="cmaes")  # the swing-up's preset is PGPE's
    assert cmaes.search.name == "cmaes" and cmaes.search.popsize == 200 and cmaes.policy == "mlp:16"
    with pytest.raises(ValidationError) as error:
        TrainConfig(env="cartpole-swingup", search="cmaes", sigma_lr=0.1)
    assert "sigma_lr: a setting of the pgpe search, not of cmaes" in describe_errors(error.value)


def test_the_flat_form_goes_there_and_back():
    for config in (
        TrainConfig(env="cartpole-swingup", model_based={}),
        TrainConfig(search="enac"),
        TrainConfig(env="baxter-stack-end-point"),
        TrainConfig(env="Pendulum-v1"),
    ):
        assert TrainConfig.model_validate(nested(flattened(config))) == config
        assert TrainConfig.model_validate_json(config.model_dump_json()) == config


def test_show_settings_says_where_each_setting_came_from(tmp_path):
    (tmp_path / "c.toml").write_text("popsize = 100\n")
    arguments = ["train", "cartpole-swingup", "--model-based", "--config", str(tmp_path / "c.toml"), "--seed", "3"]
    result = CliRunner().invoke(main, [*arguments, "--show-settings"])
    assert result.exit_code == 0, result.output
    lines = {line.split(" = ")[0]: line for line in result.output.splitlines() if " = " in line}
    assert lines["budget"].endswith("# preset swing-up model-based")
    assert lines["popsize"].endswith(f"# file {tmp_path / 'c.toml'}")
    assert lines["seed"].endswith("# flag") and lines["sampler"].endswith("# default")
    assert lines["model_kind"].endswith("# preset swing-up model-based")
    assert not (Path("runs").exists() and any("swingup" in path.name for path in Path("runs").iterdir()))


def test_set_reaches_any_setting_and_refuses_what_is_not_one(tmp_path):
    result = CliRunner().invoke(
        main,
        [
            "train",
            "cartpole",
            "--model-based",
            "--set",
            "model_based.disagreement_penalty=0.5",
            "--set",
            "model_based.hidden=[8, 8]",
            "--show-settings",
        ],
    )
    assert result.exit_code == 0, result.output
    assert re.search(r"disagreement_penalty = 0.5 +# flag", result.output)
    assert re.search(r"hidden = \[8, 8\] +# flag", result.output)
    refused = CliRunner().invoke(main, ["train", "cartpole", "--set", "model_based.no_such=1"])
    assert refused.exit_code == 2 and "'model_based.no_such' is not a setting" in refused.output
    alone = CliRunner().invoke(main, ["train", "cartpole", "--set", "model_based.ensemble_size=5"])
    assert alone.exit_code == 2 and "settings of a model-based run only; add --model-based" in alone.output


def test_a_run_folder_an_older_drrl_wrote_is_read_and_evaluated(tmp_path):
    config = TrainConfig(budget=16, eval_episodes=2)
    train(config, out=tmp_path / "run")
    folder = RunFolder(tmp_path / "run")
    older = {  # an older drrl's config.json: every setting of every part, flat
        **flattened(config),
        "sampler": "symmetric",
        "observation_norm": False,
        "demonstrations": 0,
        "demonstration_rounds": 1,
        "model_based": None,
        "start_from": None,
    }
    (folder.path / "config.json").write_text(json.dumps(older))
    checkpoint = folder.load_checkpoint()
    checkpoint["config"] = older
    folder.save_checkpoint(checkpoint)
    assert folder.read_config() == folder.load_run()[0]
    result = CliRunner().invoke(main, ["eval", str(folder.path), "--episodes", "2"])
    assert result.exit_code == 0, result.output


def test_a_task_s_default_kind_of_run_gives_way_to_the_one_asked_for(tmp_path):
    def kind(*args: str) -> str:
        result = CliRunner().invoke(main, ["train", *args, "--show-settings"])
        assert result.exit_code == 0, result.output
        return result.output.splitlines()[0]

    assert kind("baxter-reach") == "settings of a model-based run on baxter-reach:"  # the reach's measured default
    assert 'model_kind = "linear"' in CliRunner().invoke(main, ["train", "baxter-reach", "--show-settings"]).output
    assert kind("baxter-reach", "--model-free") == "settings of a model-free run on baxter-reach:"
    assert kind("baxter-reach", "--search", "enac") == "settings of an action-space run on baxter-reach:"
    assert kind("cartpole") == "settings of a model-free run on cartpole:"
    assert kind("Pixels/Pendulum-v1") == "settings of a model-based run on Pixels/Pendulum-v1:"  # frames need a model
    assert kind("cartpole", "--model-based") == "settings of a model-based run on cartpole:"
    file = tmp_path / "mb.toml"
    file.write_text('env = "cartpole"\n[model_based]\nensemble_size = 2\n')
    assert kind("--config", str(file)) == "settings of a model-based run on cartpole:"
    assert kind("--config", str(file), "--model-free") == "settings of a model-free run on cartpole:"
    # a setting only model-free runs have (a file written for one, a flag) keeps a model-based task's run model-free
    assert kind("baxter-reach", "--observation-norm") == "settings of a model-free run on baxter-reach:"
    both_arms = SOURCE.parents[1] / "configs" / "baxter-reach-both-arms.toml"  # no world-model table, a curriculum
    assert kind("--config", str(both_arms)) == "settings of a model-free run on baxter-reach-targets:"
    refused = CliRunner().invoke(main, ["train", "baxter-reach", "--model-free", "--ensemble", "3"])
    assert (
        refused.exit_code == 2 and "--ensemble: settings of a model-based run only; drop --model-free" in refused.output
    )


def test_a_task_no_method_learns_yet_says_so_and_names_the_closest_before_any_work(tmp_path):
    (tmp_path / "taken").write_text("")  # a run folder that cannot be made: the note comes before that refusal
    result = CliRunner().invoke(main, ["train", "baxter-stack", "--out", str(tmp_path / "taken" / "run")])
    assert result.exit_code == 2 and "refused" not in result.output.split("note:")[0]
    assert "note: no method of drrl learns baxter-stack yet; what comes closest is baxter-stack-end-point" in (
        result.output
    )
    assert not_learned("baxter-stack-end-point") is None and not_learned("cartpole") is None
    joint_targets = not_learned("baxter-reach-right-targets") or ""
    assert "closest is baxter-reach-right, the same reach with velocity actions" in joint_targets
