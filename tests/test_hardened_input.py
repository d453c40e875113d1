"""Bad input is refused with its own message: malformed configs, damaged checkpoints, non-finite env output."""

import json
import os
import shutil
import sys

import gymnasium
import numpy as np
import pytest
import torch
from click.testing import CliRunner
from safetensors import safe_open
from safetensors.torch import save_file

from drrl.cli import main
from drrl.runs import CHECKPOINT, CONFIG, METRICS, RunFolder
from drrl.settings.flat import FLAT


def train(*args):
    return CliRunner().invoke(main, ["train", *args])


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("typo.toml", "popsise = 8\n", "popsise: not a setting (did you mean popsize?); the settings are: env, policy"),
        (
            "type.toml",
            'popsize = "eight"\n',
            "popsize: must be a number, not text (got 'eight')",
        ),
        ("range.toml", "eval_every = 0\n", "eval_every: Input should be greater than or equal to 1 (got 0)"),
        ("infinite.toml", "sigma_init = inf\n", "sigma_init: Input should be a finite number (got inf)"),
        (
            "choice.json",
            '{"sampler": "genetic"}',
            "sampler: 'genetic' is not one of: single, symmetric, supersymmetric (got 'genetic')",
        ),
        ("pairs.toml", "popsize = 7\n", "symmetric sampling needs an even popsize (pairs μ ± ε), got 7"),
        ("truncated.toml", "popsize = 8\nbudget = ", "is not valid TOML: Invalid value (at end of document)"),
        ("truncated.json", '{"popsize": 8, "bud', "is not valid JSON: Unterminated string"),
        ("binary.toml", b"\x00\xff\xfe garbage", "is not TOML text: byte 1 is not UTF-8"),
        ("list.json", "[1, 2]", "must hold an object of settings (name: value), not a list"),
        ("missing.toml", None, "cannot read config file"),
        ("device.toml", 'device = "potato"\n', "device: not a torch device; usable here: cpu"),
        ("meta.toml", 'device = "meta"\n', "device: drrl runs on cpu or cuda"),
        ("deep.toml", "a = " + "{b = " * 2000 + "1" + "}" * 2000 + "\n", "nests its tables too deeply"),
        ("huge.toml", "# " + "x" * 2**20 + "\n", "is over 1024 KiB"),
        ("flag.toml", "model_based = true\n", "model_based: Input should be a valid dictionary"),
        (
            "penalty.toml",
            "[model_based]\ndisagreement_penalty = inf\n",
            "disagreement_penalty: Input should be a finite",
        ),
        ("unfold.toml", "[model_based]\nunfold = 1000000000\n", "unfold: Input should be less than or equal to 10000"),
        ("width.toml", "[model_based]\nhidden = [100000000]\n", "every layer width must be in [1, 65536]"),
        ("budget.toml", "budget = 1e25\n", "budget: Unable to parse input string as an integer"),
        ("seed.toml", "seed = 18446744073709551616\n", "seed: Input should be less than or equal to 4294967295"),
        ("lr.toml", "center_lr = 1e308\n", "center_lr: Input should be less than or equal to 1000000"),
        ("nested.toml", "[model_based]\nunfoldd = 3\n", "model_based.unfoldd: not a setting (did you mean unfold?)"),
    ],
)
def test_malformed_config_files_are_refused_each_with_its_own_message(tmp_path, name, text, message):
    """Each refused before any work, in one message, without a traceback."""
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    elif text is not None:
        path.write_text(text)
    result = train("--config", str(path), "--out", str(tmp_path / "run"), "--quiet")
    assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A small finished run, copied by each test before it damages the copy."""
    out = tmp_path_factory.mktemp("good") / "run"
    result = train("cartpole", "--budget", "24", "--popsize", "8", "--eval-episodes", "2", "--quiet", "--out", str(out))
    assert result.exit_code == 0, result.output
    return out


def rewrite_checkpoint(folder: RunFolder, change) -> None:
    state = folder.load_checkpoint()
    change(state)
    folder.save_checkpoint(state)


def edit_config(folder: RunFolder, **settings) -> None:
    """config.json with settings, given by their flat names, replaced where config.json holds them."""
    config = json.loads((folder.path / CONFIG).read_text())
    for name, value in settings.items():
        *parts, leaf = FLAT[name].path if name in FLAT else (name,)
        target = config
        for part in parts:
            target = target[part]
        target[leaf] = value
    (folder.path / CONFIG).write_text(json.dumps(config))


def rename_digest(folder: RunFolder, key: str) -> None:
    """The checkpoint with its digest under another key and a flipped data bit."""
    file = folder.path / CHECKPOINT
    with safe_open(file, framework="pt") as handle:
        tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118 (not iterable)
        metadata = handle.metadata()
    metadata[key] = metadata.pop("sha256")
    tensors["/center"][0] += 1.0
    save_file(tensors, file, metadata=metadata)


def flip_last_data_byte(file):
    data = bytearray(file.read_bytes())
    data[-1] ^= 0x01
    file.write_bytes(bytes(data))


DAMAGE = {
    "empty": (lambda f: (f.path / CHECKPOINT).write_bytes(b""), "is empty"),
    "cut in its header": (
        lambda f: (f.path / CHECKPOINT).write_bytes((f.path / CHECKPOINT).read_bytes()[:40]),
        "is truncated: its header alone needs",
    ),
    "cut in its data": (
        lambda f: (f.path / CHECKPOINT).write_bytes((f.path / CHECKPOINT).read_bytes()[:-30]),
        "is truncated or has bytes appended",
    ),
    "not safetensors": (
        lambda f: (f.path / CHECKPOINT).write_text("centre = [1, 2, 3]\n" * 4),
        "is not a safetensors file",
    ),
    "a pickle": (
        lambda f: torch.save({"center": torch.zeros(3)}, f.path / CHECKPOINT),
        "is a pickle or torch.save file; drrl never loads pickles",
    ),
    "a flipped bit": (
        lambda f: flip_last_data_byte(f.path / CHECKPOINT),
        "is corrupted: its contents do not match their SHA-256 digest",
    ),
    "foreign safetensors": (
        lambda f: save_file({"weight": torch.zeros(2)}, f.path / CHECKPOINT),
        "holds no drrl state: not a drrl checkpoint",
    ),
    "model-based": (
        lambda f: rewrite_checkpoint(f, lambda s: s.update(kind="model-based")),
        "checkpoint is of kind 'model-based' but the run's config is 'model-free'",
    ),
    "an old format": (
        lambda f: rewrite_checkpoint(f, lambda s: [s.pop(k) for k in ("wall_time", "real_steps")]),
        "checkpoint lacks wall_time, real_steps",
    ),
    "a negative counter": (
        lambda f: rewrite_checkpoint(f, lambda s: s.update(iteration=-2)),
        "checkpoint's iteration is -2; it must be a whole number from 0 to 2**53",
    ),
    "a NaN centre": (
        lambda f: rewrite_checkpoint(f, lambda s: s["center"].fill_(float("nan"))),
        "checkpoint's center must be 4 finite float32 numbers (its num_params)",
    ),
    "a float64 centre": (
        lambda f: rewrite_checkpoint(f, lambda s: s.update(center=s["center"].double())),
        "checkpoint's center must be 4 finite float32 numbers (its num_params)",
    ),
    "a wrong-shaped centre": (
        lambda f: rewrite_checkpoint(f, lambda s: s.update(best_center=torch.zeros(4, 1))),
        "checkpoint's best_center must be 4 finite float32 numbers (its num_params)",
    ),
    "another policy": (
        lambda f: edit_config(f, policy="mlp:2"),
        "(policy: 'mlp:2' in config.json, 'linear:nobias' when trained)",
    ),
    "another sampler": (
        lambda f: edit_config(f, sampler="single"),
        "(sampler: 'single' in config.json, 'symmetric' when trained)",
    ),
    "another seed": (lambda f: edit_config(f, seed=5), "(seed: 5 in config.json, 0 when trained)"),
    "another world": (
        lambda f: edit_config(f, world={"kind": "model-based"}),
        "config.json differs from the settings its checkpoint was trained with (checkpoint_every: None in config.json",
    ),
    "no digest": (lambda f: rename_digest(f, "sha257"), "has no SHA-256 digest, so its contents cannot be checked"),
    "a truncated config": (
        lambda f: (f.path / CONFIG).write_text((f.path / CONFIG).read_text()[:50]),
        "config.json is not JSON: ",
    ),
    "an edited config": (
        lambda f: edit_config(f, popsize=0),
        "popsize: Input should be greater than or equal to 2 (got 0)",
    ),
    "no metrics": (lambda f: (f.path / METRICS).unlink(), "metrics.csv is missing; it needs one row per generation"),
    "missing metrics rows": (
        lambda f: (f.path / METRICS).write_text("".join((f.path / METRICS).read_text().splitlines(keepends=True)[:2])),
        "metrics.csv is not the one its checkpoint recorded: its first 3 rows were edited, cut or come from another",
    ),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_resume_refuses_a_damaged_run_folder_each_with_its_own_message(tmp_path, finished, damage):
    spoil, message = DAMAGE[damage]
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    spoil(RunFolder(out))
    result = train("--resume", str(out))
    assert result.exit_code == 1 and f"cannot resume {out}: " in result.output, result.output
    assert message in result.output, result.output


@pytest.mark.parametrize(
    "damage",
    [
        "a flipped bit",
        "no digest",
        "another policy",
        "another seed",
        "a float64 centre",
        "a wrong-shaped centre",
        "a NaN centre",
        "model-based",
    ],
)
@pytest.mark.parametrize("command", ["eval", "render"])
def test_eval_and_render_refuse_what_resume_refuses(tmp_path, finished, damage, command):
    spoil, message = DAMAGE[damage]
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    spoil(RunFolder(out))
    video = ["--out", str(tmp_path / "x.gif")] if command == "render" else []
    result = CliRunner().invoke(main, [command, str(out), *video])
    assert result.exit_code == 1 and message in result.output, result.output
    assert "Traceback" not in result.output and not (tmp_path / "x.gif").exists()


class NaNObservationEnv(gymnasium.Env):
    """Observes NaN once its first action is positive."""

    observation_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.ones(2, np.float32), {}

    def step(self, action):
        value = np.nan if action[0] > 0 else 1.0
        return np.full(2, value, np.float32), 0.0, False, False, {}


def test_a_non_finite_observation_stops_the_run_with_a_message_and_a_checkpoint(tmp_path):
    gymnasium.register("drrl-test/NaNObservation-v0", entry_point=NaNObservationEnv, max_episode_steps=5)
    out = tmp_path / "run"
    result = train(
        "--env",
        "drrl-test/NaNObservation-v0",
        "--budget",
        "8",
        "--popsize",
        "4",
        "--eval-episodes",
        "1",
        "--quiet",
        "--out",
        str(out),
    )
    assert result.exit_code == 1, result.output
    assert "generation 1: the environment returned a non-finite observation [nan nan] at step 1 of candidate" in (
        result.output
    )
    assert f"run folder and checkpoint (generation 0) kept: {out}" in result.output
    assert RunFolder(out).load_checkpoint()["iteration"] == 0


def test_the_ray_backend_without_ray_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now fails, as when it is not installed
    monkeypatch.delitem(sys.modules, "drrl.rollout.ray", raising=False)
    result = train("cartpole", "--backend", "ray", "--quiet", "--out", str(tmp_path / "run"))
    assert result.exit_code == 2 and 'needs Ray, which is not installed: pip install "drrl[ray]"' in result.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["--env", ""], "the environment name is empty"),
        (["--env", "CartPol-v1"], "did you mean CartPole-v1"),
        (["--env", "x" * 10_000], "unknown environment 'xxx"),
        (["cartpole", "--policy", "rnn:٣"], "malformed policy spec 'rnn:٣'"),
        (["cartpole", "--popsize", "٨"], "'٨' is not a whole number in the digits 0-9"),
        (["cartpole", "--policy", "mlp:100000000"], "malformed policy spec 'mlp:100000000'"),
        (
            ["cartpole", "--policy", "mlp:65536,65536", "--popsize", "100000", "--budget", "100000"],
            "GiB (100000 candidates of a 4,295,426,049-weight mlp:65536,65536 policy",
        ),
    ],
)
def test_bad_flags_are_refused_in_one_short_line_before_any_work(tmp_path, args, message):
    result = train(*args, "--out", str(tmp_path / "run"), "--quiet")
    assert result.exit_code == 2 and message in result.output, result.output
    assert len(result.output) < 600 and not (tmp_path / "run").exists()


def test_a_config_file_may_start_with_a_byte_order_mark(tmp_path):
    (tmp_path / "bom.toml").write_bytes("\ufeffpopsize = 8\nbudget = 16\n".encode())
    result = train("--config", str(tmp_path / "bom.toml"), "--out", str(tmp_path / "run"), "--quiet")
    assert result.exit_code == 0 and "done: 2 generations" in result.output, result.output


def test_a_read_only_run_folder_is_refused_before_any_work(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root may write into a read-only folder")
    out = tmp_path / "run"
    out.mkdir()
    out.chmod(0o500)
    try:
        result = train("cartpole", "--out", str(out), "--quiet")
    finally:
        out.chmod(0o700)
    assert result.exit_code == 2 and "is not writable" in result.output, result.output


@pytest.mark.parametrize(
    "args",
    [
        [
            "--eval-episodes",
            "100000",
            "--popsize",
            "1000000",
            "--episodes-per-candidate",
            "1000",
            "--budget",
            "1000000000",
        ],
        ["--model-based", "--model-hidden", "65536,65536", "--ensemble", "1000"],
    ],
)
def test_a_run_too_big_for_memory_is_refused_before_any_work(tmp_path, args):
    result = train("cartpole", *args, "--out", str(tmp_path / "run"), "--quiet")
    assert result.exit_code == 2 and "GiB free; use a smaller policy, popsize" in result.output, result.output
    assert not (tmp_path / "run").exists()
