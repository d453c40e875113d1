"""A sweep of generated settings and config files: every one is either accepted or refused with a message, never a
traceback; and every accepted one prepares a run or is refused before any work."""

import math
import string

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from drrl.settings import ModelBasedSettings, TrainConfig, describe_errors, load_config_file
from drrl.settings.flat import FLAT
from drrl.training.train import prepare

VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12)
    | st.sampled_from(
        [
            "cartpole",
            "cartpole-po",
            "Pendulum-v1",
            "linear",
            "mlp:4",
            "rnn:2",
            "cmaes",
            "symmetric",
            "reinforce",
            "cpu",
            "cuda",
            "lstm",
        ]
    ),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3),
    max_leaves=6,
)
PLAUSIBLE = st.one_of(
    st.integers(0, 64),
    st.floats(0.001, 3.0),
    st.sampled_from(
        [
            "cartpole",
            "cartpole-po",
            "cartpole-swingup",
            "linear",
            "linear:nobias",
            "mlp:4",
            "rnn:2",
            "lstm:2",
            "cmaes",
            "sep-cmaes",
            "pgpe",
            "symmetric",
            "supersymmetric",
            "centered_ranks",
            "adam",
            "sgd",
            "lstm",
            "rnn",
            "known",
        ]
    ),
    VALUES,
)  # three parts in four near what a user writes, one part anything
FIELDS = st.sampled_from(
    [
        *(name for name in FLAT if not name.startswith("model_based.")),
        "search",
        "model_based.hidden",
        "model_based.unfold",
        "model_based.reward",
        "model_based.generations_per_iteration",
        "popsise",
        "model-based",
    ]
)


@st.composite
def setting_dicts(draw):
    chosen = {}
    for name in draw(st.lists(FIELDS, max_size=4, unique=True)):
        if name.startswith("model_based."):
            table = chosen.setdefault("model_based", {})
            if isinstance(table, dict):
                table[name.split(".", 1)[1]] = draw(PLAUSIBLE)
        else:
            chosen[name] = draw(PLAUSIBLE)
    return chosen


def small(config: TrainConfig) -> bool:
    """Cheap enough to build here: the envs of a generation and of the measurements."""
    return config.episodes_per_generation <= 256 and config.measuring.eval_episodes <= 256


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(setting_dicts())
@pytest.mark.slow
def test_generated_settings_are_accepted_or_refused_with_a_message(chosen):
    try:
        config = TrainConfig.model_validate(chosen)
    except ValidationError as error:
        message = describe_errors(error)
        assert message and "Traceback" not in message
        return
    search = config.search
    assert all(math.isfinite(value) for value in (search.sigma_init, getattr(search, "center_lr", 1.0)))
    assert config.model_based is None or isinstance(config.model_based, ModelBasedSettings)
    if small(config):
        try:
            prepare(config).close()
        except ValueError as error:  # an unknown env or policy, a space drrl cannot use: before any work
            assert str(error)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet=string.printable + "\ufeff=[]{}\"'", max_size=200), st.sampled_from([".toml", ".json"]))
def test_generated_config_files_are_read_or_refused_with_a_message(tmp_path_factory, text, suffix):
    path = tmp_path_factory.mktemp("config") / f"settings{suffix}"
    path.write_text(text)
    try:
        settings_read = load_config_file(path)
    except ValueError as error:
        assert str(path) in str(error)
        return
    assert isinstance(settings_read, dict)


FLAGS = [
    "--policy",
    "--search",
    "--sampler",
    "--optimizer",
    "--fitness-shaping",
    "--popsize",
    "--episodes-per-candidate",
    "--budget",
    "--sigma-init",
    "--center-lr",
    "--sigma-lr",
    "--eval-episodes",
    "--eval-every",
    "--seed",
    "--checkpoint-every",
    "--model-based",
    "--model-kind",
    "--model-hidden",
    "--overshoot",
    "--ensemble",
    "--generations-per-iteration",
    "--backend",
    "--workers",
    "--env",
    "--bogus",
]
FLAG_VALUES = st.one_of(
    st.integers(-3, 300).map(str),
    st.floats(allow_nan=True).map(str),
    st.text(max_size=8),
    st.sampled_from(["cartpole", "mlp:4", "rnn:2", "cmaes", "8", "0.1", "٨", "", "1e308"]),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(FLAGS), FLAG_VALUES), max_size=4))
def test_generated_flags_start_a_run_or_are_refused_in_one_message(tmp_path_factory, flags):
    from click.testing import CliRunner

    import drrl.cli.commands

    prepared = []
    original = drrl.cli.commands.run_and_report
    drrl.cli.commands.run_and_report = lambda setup, folder, attached, counters=None: prepared.append(setup.close())
    try:
        args = [part for flag, value in flags for part in ((flag,) if flag == "--model-based" else (flag, value))]
        out = tmp_path_factory.mktemp("flags") / "run"
        result = CliRunner().invoke(drrl.cli.main, ["train", *args, "--out", str(out), "--quiet"])
    finally:
        drrl.cli.commands.run_and_report = original
    assert result.exit_code in (0, 2), (args, result.output, result.exception)
    assert result.exit_code == 0 or (isinstance(result.exception, SystemExit) and "Error" in result.output), args
    assert (result.exit_code == 0) == bool(prepared), args
