"""What a user or a file gives drrl is refused in one line or taken correctly, on every input path: config files
(any type of file, TOML's booleans, JSON's repeated keys), flags, and run folders whose metrics or checkpoint were
edited (a forged checkpoint has its digest recomputed, as drrl's own writer would)."""

import http.server
import os
import resource
import shutil
import subprocess
import sys
import threading
import time

import pytest
from click.testing import CliRunner

from drrl.cli import main
from drrl.runs import CHECKPOINT, CONFIG, METRICS, RunFolder


def drrl(*args):
    return CliRunner().invoke(main, [str(arg) for arg in args])


def one_line_refusal(result, code: int, message: str) -> None:
    """Refused with exit ``code`` and ``message`` in a short message, no traceback."""
    assert result.exit_code == code, result.output
    assert message in result.output, result.output
    assert "Traceback" not in result.output and len(result.output) < 1000, result.output


# ------------------------------------------------------------------------------------------------ config files


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("bool.toml", "seed = true\n", "seed: must be a number, not true/false"),
        ("bool2.toml", "eval_episodes = false\n", "eval_episodes: must be a number, not true/false"),
        ("bool3.toml", "max_steps = true\n", "max_steps: must be a number, not true/false"),
        ("bool4.toml", "checkpoint_every = true\n", "checkpoint_every: must be a number, not true/false"),
        (
            "bool5.toml",
            "demonstrations = 4\ndemonstration_noise = true\n",
            "demonstration_noise: must be a number, not true/false",
        ),
        ("text.toml", 'popsize = "1_0"\n', "popsize: must be a number, not text"),
        ("table.toml", "[model_based]\nensemble_size = true\n", "model_based.ensemble_size: must be a number"),
        ("widths.toml", "[model_based]\nhidden = [true]\n", "model_based.hidden: item 1: must be a number"),
        ("twice.json", '{"budget": 3, "budget": 5}', "is not a drrl config: 'budget' is given twice"),
        ("huge.toml", f"seed = {'9' * 5000}\n", "holds a number too long to be a setting"),
        ("upper.JSON", '{"popsize": 7}', "symmetric sampling needs an even popsize"),  # read as JSON, then judged
    ],
)
def test_a_config_file_with_a_value_of_the_wrong_kind_is_refused_naming_it(tmp_path, name, text, message):
    (tmp_path / name).write_text(text)
    one_line_refusal(drrl("train", "cartpole", "--config", tmp_path / name, "--show-settings"), 2, message)


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_a_config_that_is_not_a_regular_file_is_refused_without_reading_it(tmp_path, special):
    if special == "fifo":
        special = tmp_path / "config.toml"
        os.mkfifo(special)  # no writer: opening it would block forever
    one_line_refusal(drrl("train", "--config", special, "--show-settings"), 2, "is not a regular file")


# ------------------------------------------------------------------------------------------------ flags


@pytest.mark.parametrize(
    "args, message",
    [
        (["train", "cartpole", "--workers", "nan"], "'nan' is not a whole number ≥ 1"),
        (["train", "cartpole", "--workers", "1e3"], "'1e3' is not a whole number ≥ 1"),
        (["train", "cartpole", "--seed", "9" * 5000], "has 5000 digits"),
        (["compare", "--budget", "nan"], "'nan' is not a whole number ≥ 1"),
        (["train", "cartpole", "--search", "reinforce", "--sigma-init", "1e-320"], "a smaller σ is 0 in float32"),
        (["train", "cartpole", "--model-based", "--model-hidden", "٦٤"], "'٦٤' is not a whole number in the digits"),
        (["train", "cartpole", "--model-based", "--model-hidden", "1_0"], "'1_0' is not a whole number in the digits"),
        (
            ["train", "cartpole", "--model-based", "--set", "model_based.exploration_bonus=1e308"],
            "model_based.exploration_bonus: Input should be less than or equal to 1000000",
        ),
        (["train", "cartpole", "--backend", "ray", "--address", "[::1]:99999"], "port 99999 is out of range"),
    ],
)
def test_a_bad_number_flag_says_what_is_allowed(args, message):
    one_line_refusal(drrl(*args), 2, message)


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """Two small finished runs of seeds 0 and 1, copied by each test before it damages the copy."""
    runs = []
    for seed in (0, 1):
        out = tmp_path_factory.mktemp("good") / "run"
        result = drrl(
            *("train", "cartpole", "--budget", 24, "--popsize", 8, "--eval-episodes", 2, "--seed", seed),
            *("--quiet", "--out", out),
        )
        assert result.exit_code == 0, result.output
        runs.append(out)
    return runs


@pytest.fixture
def copy(tmp_path, finished):
    out = tmp_path / "run"
    shutil.copytree(finished[0], out)
    return out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--seed", "-1"], "-1 is not a whole number from 0 to 4294967295"),
        (["--episodes", "100000000000"], "100000000000 is not a whole number from 1 to 10000"),
        (["--episodes", "nan"], "'nan' is not a whole number from 1 to 10000"),
        (["--env", ""], "the environment name is empty"),
    ],
)
def test_eval_refuses_a_bad_flag_before_measuring(copy, args, message):
    one_line_refusal(drrl("eval", copy, *args), 2 if "--env" not in args else 1, message)


# ------------------------------------------------------------------------------------------------ run folders


def edit_metrics(folder, change) -> None:
    """metrics.csv with ``change`` applied to its lines (header first), written back as text."""
    file = folder / METRICS
    lines = file.read_text().splitlines(keepends=True)
    file.write_text("".join(change(lines)))


def cell(line: str, column: int, value: str) -> str:
    values = line.rstrip("\r\n").split(",")
    values[column] = value
    return ",".join(values) + "\r\n"


def forge(folder, **values) -> None:
    """The checkpoint with ``values`` put in and its digest recomputed."""
    run = RunFolder(folder)
    state = run.load_checkpoint()
    state.update(values)
    if "metrics" in values:  # drrl's writer would record the rows' own digest
        run._metrics_record = lambda rows: values["metrics"]
    run.save_checkpoint(state)


def balanced_column(folder) -> int:
    return (folder / METRICS).read_text().splitlines()[0].split(",").index("balanced")


METRICS_EDITS = {
    "an edited value": lambda f: edit_metrics(f, lambda lines: [lines[0], cell(lines[1], 3, "9999"), *lines[2:]]),
    "swapped header names": lambda f: edit_metrics(
        f, lambda lines: [",".join(reversed(lines[0].rstrip().split(","))) + "\r\n", *lines[1:]]
    ),
    "another seed's file": None,  # copied in by the test
    "a generation of 1.5": lambda f: edit_metrics(f, lambda lines: [lines[0], cell(lines[1], 0, "1.5"), *lines[2:]]),
    "a generation of inf": lambda f: edit_metrics(f, lambda lines: [lines[0], cell(lines[1], 0, "inf"), *lines[2:]]),
    "a generation of nan": lambda f: edit_metrics(f, lambda lines: [lines[0], cell(lines[1], 0, "nan"), *lines[2:]]),
    "balanced set to 7": lambda f: edit_metrics(
        f, lambda lines: [lines[0], cell(lines[1], balanced_column(f), "7"), *lines[2:]]
    ),
}


@pytest.mark.parametrize("edit", list(METRICS_EDITS))
def test_resume_refuses_metrics_that_are_not_the_ones_its_checkpoint_recorded(copy, finished, edit):
    if METRICS_EDITS[edit] is None:
        shutil.copy(finished[1] / METRICS, copy / METRICS)
    else:
        METRICS_EDITS[edit](copy)
    before = (copy / METRICS).read_bytes()
    result = drrl("train", "--resume", copy)
    one_line_refusal(result, 1, "metrics.csv is not the one its checkpoint recorded")
    assert (copy / METRICS).read_bytes() == before  # nothing written back


@pytest.mark.parametrize(
    "values, message",
    [
        ({"wall_time": None}, "checkpoint's wall_time is None; it must be a number of seconds >= 0"),
        ({"wall_time": -1e9}, "checkpoint's wall_time is -1000000000.0"),
        ({"best_center_return": None}, "checkpoint's best_center_return is None"),
        ({"best_center_return": "abc"}, "checkpoint's best_center_return is 'abc'"),
        ({"real_episodes": 10**30}, "checkpoint's real_episodes is 1000000000000000000000000000000"),
        ({"real_episodes": 10**6, "real_steps": 10**7}, "checkpoint's real_episodes is 1000000, past the run's 24"),
        ({"best_iteration": 99}, "checkpoint's best_iteration (99) is past its iteration (3)"),
        ({"real_steps": 3}, "checkpoint's real_steps (3) is fewer than its real_episodes"),
        ({"best_center_criteria": 5}, "checkpoint's best_center_criteria is 5; drrl/CartPole-v0 has 2 criteria"),
        ({"metrics": {"rows": 3, "bytes": -1, "sha256": "0" * 64}}, "record of its metrics rows is"),
        ({"env_id": "CartPole-v1"}, "checkpoint's env_id 'CartPole-v1' does not match config.json's env cartpole"),
    ],
)
@pytest.mark.parametrize("command", ["resume", "eval"])
def test_a_forged_checkpoint_is_refused_naming_the_value(copy, values, message, command):
    forge(copy, **values)
    args = ["train", "--resume", copy] if command == "resume" else ["eval", copy]
    if (command == "eval" and "past the run's" in message) or "criteria" in message:
        pytest.skip("eval does not build the run, whose budget and criteria this needs")
    one_line_refusal(drrl(*args), 1, message)


def test_metrics_whose_step_column_is_not_a_count_are_named_when_plotted(copy):
    METRICS_EDITS["a generation of inf"](copy)
    with pytest.raises(ValueError, match=r"metrics.csv is damaged \(line 2's generation is 'inf', not 1\)"):
        RunFolder(copy).read_metrics()


def test_a_checkpoint_recording_settings_from_before_one_existed_is_read_with_its_default(copy):
    run = RunFolder(copy)
    state = run.load_checkpoint()
    del state["config"]["measuring"]["solved_in_a_row"]  # as a drrl without that setting recorded it
    run.save_checkpoint(state)
    result = drrl("eval", copy, "--episodes", 2)
    assert result.exit_code == 0 and "balanced:" in result.output, result.output


# ------------------------------------------------------------------------------------------------ places to write


@pytest.mark.parametrize(
    "out, message",
    [
        ("a" * 300, "has a name of 300 bytes"),
        ("/".join(["b" * 200] * 25), "is a path of 5"),
        ("afile/run", "which is a file, not a folder"),
    ],
)
def test_an_output_place_that_cannot_be_written_is_refused_before_any_work(tmp_path, out, message):
    (tmp_path / "afile").write_text("")
    one_line_refusal(drrl("train", "cartpole", "--out", tmp_path / out, "--quiet"), 2, message)
    one_line_refusal(drrl("compare", "--out", tmp_path / out, "--budget", 16), 2, message)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["afile"]


@pytest.mark.parametrize(
    "video, message",
    [("r" * 300 + ".gif", "has a name of 304 bytes"), ("/proc/version.gif", "nothing can be made in /proc")],
)
def test_render_refuses_a_video_it_could_not_write_before_recording(copy, video, message):
    result = drrl("render", copy, "--out", video if video.startswith("/") else copy.parent / video)
    one_line_refusal(result, 1, message)


def test_render_makes_the_video_s_missing_folders(copy):
    video = copy.parent / "videos" / "of" / "run.gif"
    result = drrl("render", copy, "--out", video)
    assert result.exit_code == 0 and video.stat().st_size > 0, result.output


def test_compare_takes_its_env_from_the_config_file(tmp_path):
    (tmp_path / "ne.toml").write_text('env = "nonexistent-v0"\n')
    one_line_refusal(drrl("compare", "--config", tmp_path / "ne.toml", "--out", tmp_path / "c"), 2, "nonexistent-v0")
    result = drrl("compare", "--config", tmp_path / "ne.toml", "--env", "cartpole", "--out", tmp_path / "c")
    one_line_refusal(result, 2, "two environments given: 'nonexistent-v0' in")


def test_a_family_prefix_of_a_family_member_is_refused():
    one_line_refusal(drrl("train", "--env", "Pixels/" * 400 + "CartPole-v1"), 2, "Pixels/ID takes a plain env id")


# ------------------------------------------------------------------------------------------------ stopped runs


def test_a_run_stopped_before_its_first_checkpoint_starts_again_and_gives_the_same_run(tmp_path, finished):
    out = tmp_path / "run"
    out.mkdir()
    shutil.copy(finished[0] / CONFIG, out / CONFIG)  # what a run killed while starting leaves
    one_line_refusal(drrl("eval", out), 1, "its run stopped before the first; drrl train --resume")
    result = drrl("train", "--resume", out, "--quiet")
    assert result.exit_code == 0 and "starting" in result.output and "again from its start" in result.output
    assert (out / METRICS).read_text().count("\n") == (finished[0] / METRICS).read_text().count("\n")
    same = [line.split(",")[:-1] for line in (out / METRICS).read_text().splitlines()]
    assert same == [line.split(",")[:-1] for line in (finished[0] / METRICS).read_text().splitlines()]


def test_an_interrupt_while_preparing_leaves_no_folder(tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("drrl.cli.commands.prepare", interrupted)
    one_line_refusal(drrl("train", "cartpole", "--out", tmp_path / "run"), 1, "interrupted while preparing the run")
    assert not (tmp_path / "run").exists()


def under_file_size_limit(code: str, limit: int) -> subprocess.CompletedProcess:
    """``code`` run by Python in a process that may write files of at most ``limit`` bytes (a full disk's errors)."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)),
    )


@pytest.mark.slow
def test_a_full_disk_at_the_first_checkpoint_is_one_line_and_the_run_starts_again_when_there_is_room(tmp_path):
    out = tmp_path / "run"
    arguments = ["train", "cartpole", "--policy", "mlp:32", "--budget", "48", "--out", str(out)]
    train = f"from drrl.cli import main; main({arguments!r})"
    full = under_file_size_limit(train, 4096)
    assert full.returncode == 1 and "File too large" in full.stderr and "Traceback" not in full.stderr, full.stderr
    assert sorted(path.name for path in out.iterdir()) == [CONFIG]
    result = drrl("train", "--resume", out, "--quiet")
    assert result.exit_code == 0 and "done: 6 generations" in result.output, result.output


def test_a_checkpoint_that_does_not_fit_keeps_the_last_one_whole(copy):
    before = (copy / CHECKPOINT).read_bytes()
    save = (
        f"import torch; from drrl.runs import RunFolder; run = RunFolder('{copy}'); state = run.load_checkpoint(); "
        f"state['grown'] = torch.zeros(10_000); run.save_checkpoint(state)"
    )
    full = under_file_size_limit(save, len(before) + 1000)
    assert "OSError: [Errno 27] File too large" in full.stderr and str(copy / CHECKPOINT) in full.stderr, full.stderr
    assert (copy / CHECKPOINT).read_bytes() == before and not list(copy.glob("*.tmp"))


# ------------------------------------------------------------------------------------------------ Ray


@pytest.mark.slow
def test_a_ray_address_is_checked_for_its_port_and_what_answers_there():
    pytest.importorskip("ray")
    from drrl.rollout.ray import CONNECT_TIMEOUT, _check_reachable, _host_and_port

    assert _host_and_port("[::1]:6379") == ("::1", 6379)
    assert _host_and_port("ray://10.0.0.1:10001") == ("10.0.0.1", 10001)
    with pytest.raises(ValueError, match="port 99999 is out of range; a port is from 1 to 65535"):
        _check_reachable("127.0.0.1:99999")
    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    start = time.perf_counter()
    try:
        with pytest.raises(ValueError, match=r"something answers at .*, but no Ray cluster could be joined there"):
            _check_reachable(f"127.0.0.1:{server.server_address[1]}")
    finally:
        server.shutdown()
    assert time.perf_counter() - start < CONNECT_TIMEOUT + 5


def test_an_interrupt_before_the_first_checkpoint_says_how_to_start_again(tmp_path, monkeypatch):
    def interrupted(self, state):
        raise KeyboardInterrupt  # the moment config.json is written, before the first checkpoint

    monkeypatch.setattr(RunFolder, "save_checkpoint", interrupted)
    result = drrl("train", "cartpole", "--budget", 16, "--out", tmp_path / "run", "--quiet")
    one_line_refusal(result, 1, "interrupted before the first checkpoint")
    assert f"start it again with: drrl train --resume {tmp_path / 'run'}" in result.output
    assert sorted(path.name for path in (tmp_path / "run").iterdir()) == [CONFIG]


def test_a_folder_that_lost_its_checkpoint_after_training_is_refused_not_started_again(copy):
    (copy / CHECKPOINT).unlink()
    one_line_refusal(drrl("train", "--resume", copy), 1, "has no checkpoint (checkpoint.safetensors)")
    assert (copy / METRICS).exists()


def test_a_fit_batch_too_big_for_memory_is_refused_before_any_work(tmp_path):
    result = drrl(
        *("train", "cartpole", "--model-based", "--set", "model_based.fit_batch_size=1000000", "--set"),
        *("model_based.ensemble_size=5", "--set", "model_based.hidden=[4096]", "--out", tmp_path / "run"),
    )
    one_line_refusal(result, 2, "the world model and its fitting batch")
    assert not (tmp_path / "run").exists()


def test_an_environment_variable_is_checked_as_its_flag_is(monkeypatch):
    monkeypatch.setenv("DRRL_DEBUG", "maybe")
    one_line_refusal(drrl("train", "cartpole", "--show-settings"), 2, "'maybe' is not a valid boolean")
