"""Properties over whole input paths, with inputs drawn by Hypothesis rather than listed: every config file, flag
and damaged run folder is either refused in one short line (no traceback, nothing written) or accepted and taken
correctly (the settings it gave are the run's; a run folder measures as it did before the damage)."""

import json
import math
import random
import shutil
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from drrl.cli import main
from drrl.runs import CHECKPOINT, CONFIG, METRICS, RunFolder
from drrl.settings import TrainConfig
from drrl.settings.flat import FLAT, flattened


def fuzzing(examples: int):
    """Hypothesis's settings here: ``examples`` inputs, the same ones every run (derandomized), no time limit."""
    return settings(
        max_examples=examples,
        derandomize=True,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture],
    )


NAMES = [name for name in FLAT if "." not in name and name != "env"]
VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, 1, 2, 8, 16, 0.5, 1e-320, 1e308, "8", "٨", "1_0", "", "linear", "mlp:4", "pgpe", "cmaes"]),
    st.text(max_size=12),
    st.lists(st.integers(-5, 70_000), max_size=3),
)


def drrl(*args):
    return CliRunner().invoke(main, [str(arg) for arg in args])


def refused_in_one_line(result) -> bool:
    return result.exit_code in (1, 2) and "Traceback" not in result.output and len(result.output) < 2000


def same(given, taken) -> bool:
    if isinstance(given, float) and isinstance(taken, float):
        return given == taken or (math.isnan(given) and math.isnan(taken))
    if isinstance(given, list):
        return list(taken or []) == given
    return (given == taken and type(given) is type(taken)) or (type(given) is int and taken == float(given))


@fuzzing(150)
@given(st.dictionaries(st.sampled_from([*NAMES, "popsise", "model_based"]), VALUES, max_size=4))
def test_a_config_file_is_refused_in_one_line_or_taken_as_written(tmp_path, written):
    file = tmp_path / "config.json"
    file.write_text(json.dumps({"env": "cartpole", **written}))
    result = drrl("train", "--config", file, "--show-settings")
    if result.exit_code != 0:
        assert refused_in_one_line(result), result.output
        return
    config = TrainConfig.model_validate({"env": "cartpole", **written})  # what the file's settings gave
    flat = flattened(config)
    for name, value in written.items():
        if name != "model_based" and value is not None:
            assert same(value, flat.get(name)), (name, value, flat.get(name))


@fuzzing(80)
@given(
    st.sampled_from(["--popsize", "--sigma-init", "--seed", "--budget", "--policy", "--workers", "--eval-episodes"]),
    st.one_of(st.text(max_size=10), st.integers().map(str), st.floats().map(str)),
)
def test_a_flag_is_refused_in_one_line_or_taken_as_given(option, value):
    result = drrl("train", "cartpole", option, value, "--show-settings")
    if result.exit_code != 0:
        assert refused_in_one_line(result), result.output
        return
    name = option.removeprefix("--").replace("-", "_")
    if name in FLAT:
        line = next(line for line in result.output.splitlines() if line.startswith(f"{name} = "))
        assert line.endswith("# flag"), line


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("good") / "run"
    result = drrl("train", "cartpole", "--budget", 24, "--popsize", 8, "--eval-episodes", 2, "--quiet", "--out", out)
    assert result.exit_code == 0, result.output
    return out, drrl("eval", out, "--episodes", 3).output


def damage(folder: Path, rng: random.Random) -> None:
    """One random damage: a file cut, bytes flipped, or a checkpoint entry changed with its digest recomputed."""
    how = rng.choice(["cut", "flip", "edit"])
    file = folder / rng.choice([CHECKPOINT, CONFIG, METRICS])
    data = bytearray(file.read_bytes())
    if how == "cut":
        file.write_bytes(bytes(data[: rng.randrange(len(data))]))
    elif how == "flip":
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        file.write_bytes(bytes(data))
    else:
        run = RunFolder(folder)
        state = run.load_checkpoint()
        key = rng.choice(sorted(key for key in state if key not in ("search", "world", "config")))
        state[key] = rng.choice([None, -1, 0, 1, 99, 2**60, -1e9, 1.5, float("nan"), "abc", True, [], {}])
        kept = state.get("metrics")
        run._metrics_record = lambda rows: kept  # the record as it was
        run.save_checkpoint(state)


@fuzzing(200)
@given(st.integers(0, 2**32 - 1))
@pytest.mark.slow
def test_a_damaged_run_folder_is_refused_in_one_line_or_measures_as_before(finished, seed):
    good, measured = finished
    folder = Path(tempfile.mkdtemp()) / "run"
    try:
        shutil.copytree(good, folder)
        damage(folder, random.Random(seed))
        files = {path.name: path.read_bytes() for path in folder.iterdir()}
        result = drrl("eval", folder, "--episodes", 3)
        if result.exit_code != 0:
            assert refused_in_one_line(result), result.output
        else:
            assert result.output == measured, result.output
        resumed = drrl("train", "--resume", folder, "--quiet")
        if resumed.exit_code != 0:
            assert refused_in_one_line(resumed), resumed.output
            assert {path.name: path.read_bytes() for path in folder.iterdir()} == files  # nothing written
        else:
            assert "is complete: all 3 generations done" in resumed.output, resumed.output
    finally:
        shutil.rmtree(folder.parent)


def test_the_property_s_own_check_fails_on_a_wrong_acceptance():
    """``same`` tells a setting taken otherwise than written (so the property above can fail)."""
    assert not same(8, 8.5) and not same(True, 1) and not same([64], [32]) and same(8, 8) and same(1, 1.0)
    with pytest.raises(ValidationError):
        TrainConfig.model_validate({"popsize": True})
