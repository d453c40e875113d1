"""Adversarial sweep: generated settings, damaged config files and damaged run folders, each through drrl as a user
would run it; every outcome is an acceptance, a clean refusal (one message, no traceback) or a defect.

    python benchmarks/adversarial.py --settings 3000 --files 2000 --folders 300

* settings: random TrainConfig dicts (valid, out-of-range, wrong-typed, unicode, huge values) validated and, when
  accepted and small, prepared as a run (envs, policy, search, backend built, nothing trained);
* files: a valid TOML or JSON config with random bytes flipped, cut, inserted or a byte-order mark added, read by
  `drrl train --config`;
* folders: a finished model-free and a finished model-based run with one random damage each (a truncated, extended
  or bit-flipped checkpoint, an edited or bit-flipped config.json, a renamed digest, a removed file, cut metrics),
  then `drrl eval`, `drrl train --resume` and `drrl render` on a copy. A damaged folder that a command accepts is a
  silent acceptance unless the damage left the run's meaning intact (a metrics row cut and written again on
  resume; a config edited to the values it had).

Prints a table per category: tried, accepted, refused cleanly, tracebacks (defects), silent acceptances (defects).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import tempfile
import traceback
from collections import Counter
from pathlib import Path

from click.testing import CliRunner
from pydantic import ValidationError

from drrl.cli import main
from drrl.runs import CHECKPOINT, CONFIG, METRICS, RunFolder
from drrl.settings import TrainConfig, describe_errors, load_config_file
from drrl.training.train import prepare

FORGED = [None, -1, 0, 1, 7, 99, 2**60, 10**30, -1e9, 1.5, float("nan"), float("inf"), "abc", True, [], {}]
FIELDS = [*TrainConfig.model_fields, "popsise", "model-based"]
NASTY = [
    None,
    True,
    -1,
    0,
    2**64,
    1e308,
    float("inf"),
    float("nan"),
    -0.0,
    "",
    "٣",
    "x" * 5000,
    [],
    {},
    [1, 2],
    {"hidden": [0]},
    "cartpole\x00",
    "../..",
    "1e25",
    " 8 ",
]
PLAUSIBLE = [
    1,
    2,
    4,
    8,
    16,
    0.01,
    0.1,
    1.0,
    3.0,
    "cartpole",
    "cartpole-po",
    "cartpole-swingup",
    "Pendulum-v1",
    "CartPole-v1",
    "linear",
    "linear:nobias",
    "mlp:4",
    "rnn:2",
    "lstm:2",
    "pgpe",
    "cmaes",
    "sep-cmaes",
    "symmetric",
    "reinforce",
    "supersymmetric",
    "sgd",
    "adam",
    "clipup",
    "centered_ranks",
    "none",
    "cpu",
    {},
    {"hidden": [8], "unfold": 2},
    {"generations_per_iteration": 2, "fit_updates": 10},
]


def outcome(call) -> str:
    """ "accepted", "refused" (a ValueError or a message) or "traceback: ..." for anything else."""
    try:
        call()
    except (ValueError, ValidationError):
        return "refused"
    except Exception as error:
        return f"traceback: {type(error).__name__}: {str(error)[:120]}"
    return "accepted"


def sweep_settings(rng: random.Random, count: int) -> Counter:
    results = Counter()
    for _ in range(count):
        chosen = {
            name: rng.choice(PLAUSIBLE if rng.random() < 0.7 else NASTY)
            for name in rng.sample(FIELDS, rng.randint(0, 5))
        }

        def validate_and_prepare(chosen=chosen):
            try:
                config = TrainConfig.model_validate(chosen)
            except ValidationError as error:
                describe_errors(error)  # the message itself must not fail
                raise
            if config.episodes_per_generation <= 256 and config.measuring.eval_episodes <= 256:
                prepare(config).close()

        results[outcome(validate_and_prepare)] += 1
    return results


def sweep_files(rng: random.Random, count: int, folder: Path) -> Counter:
    results = Counter()
    valid = {
        ".toml": 'env = "cartpole"\npopsize = 8\nbudget = 16\n[model_based]\nhidden = [8]\n',
        ".json": json.dumps({"env": "cartpole", "popsize": 8, "budget": 16, "model_based": {"hidden": [8]}}),
    }
    for number in range(count):
        suffix = rng.choice(list(valid))
        data = bytearray(valid[suffix].encode())
        for _ in range(rng.randint(1, 3)):
            kind, at = rng.choice(["flip", "cut", "insert", "bom"]), rng.randrange(len(data))
            if kind == "flip":
                data[at] ^= 1 << rng.randrange(8)
            elif kind == "cut":
                del data[at:]
            elif kind == "insert":
                data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
            else:
                data[:0] = b"\xef\xbb\xbf"
            if not data:
                break
        path = folder / f"config{number}{suffix}"
        path.write_bytes(bytes(data))
        results[outcome(lambda path=path: TrainConfig.model_validate(load_config_file(path)))] += 1
    return results


NUMBERS = ["8", "0", "-1", "1e3", "nan", "inf", "٨", "1_0", " 8 ", "", "9" * 25, "9" * 5000, "0x10", "8.0", "true"]
TRAIN_FLAGS = ["--popsize", "--budget", "--seed", "--workers", "--eval-episodes", "--sigma-init", "--max-steps"]
EVAL_FLAGS = ["--episodes", "--seed", "--env"]


def sweep_flags(rng: random.Random, count: int, folder: Path) -> dict[str, Counter]:
    """Random values for the number and name options of drrl train (its settings shown, nothing trained) and drrl
    eval: accepted or refused in one line, never a traceback."""
    run = folder / "flags-run"
    CliRunner().invoke(main, ["train", "cartpole", "--budget", "16", "--quiet", "--out", str(run)])
    results = {"train": Counter(), "eval": Counter()}
    for _ in range(count):
        value = rng.choice([*NUMBERS, str(rng.choice(NASTY)), "Pixels/" * rng.randint(1, 300) + "CartPole-v1"])
        if rng.random() < 0.5:
            results["train"][
                command(["train", "cartpole", rng.choice(TRAIN_FLAGS), value, "--show-settings"], run)
            ] += 1
        else:
            episodes = ["--episodes", "2"] if "--episodes" not in value else []
            results["eval"][command(["eval", str(run), *episodes, rng.choice(EVAL_FLAGS), value], run)] += 1
    return results


def sweep_places(rng: random.Random, count: int, folder: Path) -> Counter:
    """Places to write that cannot hold what is written (a name or path too long, under a file, /proc, a FIFO, a
    device) or can: drrl train --out and drrl render --out refuse the first in one line, and write the second."""
    (folder / "a-file").write_text("")
    os.mkfifo(folder / "a-fifo")
    run = folder / "places-run"
    CliRunner().invoke(main, ["train", "cartpole", "--budget", "16", "--quiet", "--out", str(run)])
    results = Counter()
    for number in range(count):
        place = rng.choice(
            [
                folder / ("n" * rng.randint(200, 300)),
                folder / "/".join(["d" * 200] * rng.randint(15, 25)),
                folder / "a-file" / "below",
                folder / "a-fifo",
                Path("/proc") / f"drrl{number}",
                Path("/dev/null") / "x",
                folder / "new" / str(number) / "deeper",
            ]
        )
        what = rng.choice(["train", "render"])
        target = place if what == "train" else place.with_suffix(".gif")
        args = (
            ["train", "cartpole", "--budget", "8", "--popsize", "8", "--quiet", "--out", str(target)]
            if what == "train"
            else ["render", str(run), "--out", str(target), "--max-steps", "3"]
        )
        got = command(args, run)
        if got == "accepted" and not (target / CHECKPOINT if what == "train" else target).is_file():
            got = f"silent acceptance: {what} claimed to write {str(target)[:60]}"
        results[got] += 1
    return results


def damage(rng: random.Random, run: Path, other: Path) -> str:
    """One random damage to ``run`` (``other``: another run of its kind); its name."""
    checkpoint, config = run / CHECKPOINT, run / CONFIG
    kind = rng.choice(
        [
            "truncate",
            "extend",
            "flip checkpoint",
            "flip config",
            "edit config",
            "rename digest",
            "remove file",
            "cut metrics",
            "forge checkpoint",
            "edit metrics",
            "another run's metrics",
        ]
    )
    if kind == "truncate":
        data = checkpoint.read_bytes()
        checkpoint.write_bytes(data[: rng.randrange(len(data))])
    elif kind == "extend":
        checkpoint.write_bytes(checkpoint.read_bytes() + bytes(rng.randint(1, 64)))
    elif kind in ("flip checkpoint", "flip config"):
        file = checkpoint if kind == "flip checkpoint" else config
        data = bytearray(file.read_bytes())
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        file.write_bytes(bytes(data))
    elif kind == "edit config":
        settings = json.loads(config.read_text())
        name = rng.choice([key for key in settings if key != "model_based"])
        settings[name] = rng.choice(PLAUSIBLE + NASTY[:9])
        config.write_text(json.dumps(settings))
    elif kind == "rename digest":
        from safetensors import safe_open
        from safetensors.torch import save_file

        with safe_open(checkpoint, framework="pt") as handle:
            tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118 (not iterable)
            metadata = handle.metadata()
        metadata["sha257"] = metadata.pop("sha256")
        save_file(tensors, checkpoint, metadata=metadata)
    elif kind == "remove file":
        (run / rng.choice([CHECKPOINT, CONFIG, METRICS])).unlink()
    elif kind == "forge checkpoint":  # an entry edited and the digest recomputed, as drrl's own writer would
        folder = RunFolder(run)
        state = folder.load_checkpoint()
        state[rng.choice(sorted(set(state) - {"search", "world", "config"}))] = rng.choice(FORGED)
        kept = state.get("metrics")
        folder._metrics_record = lambda rows: kept
        folder.save_checkpoint(state)
    elif kind == "edit metrics":
        lines = (run / METRICS).read_text().splitlines(keepends=True)
        at = rng.randrange(len(lines))
        cells = lines[at].rstrip("\r\n").split(",")
        cells[rng.randrange(len(cells))] = str(rng.choice(FORGED))
        lines[at] = ",".join(cells) + "\r\n"
        (run / METRICS).write_text("".join(lines))
    elif kind == "another run's metrics":
        shutil.copy(other / METRICS, run / METRICS)
    else:
        lines = (run / METRICS).read_text().splitlines(keepends=True)
        (run / METRICS).write_text("".join(lines[: rng.randrange(len(lines))]))
    return kind


def command(args: list[str], run: Path, expected: str | None = None) -> str:
    """ "accepted" (with the output ``expected``, the run folder's path written RUN, where given), "refused", or a
    defect."""
    result = CliRunner().invoke(main, args)
    if result.exit_code == 0:
        same = expected is None or result.output.replace(str(run), "RUN") == expected
        return "accepted" if same else "silent acceptance"
    if isinstance(result.exception, SystemExit) and "Traceback" not in result.output:
        return "refused"
    text = "".join(traceback.format_exception(result.exception))[-200:] if result.exception else result.output
    return f"traceback: {text!r}"


def sweep_folders(rng: random.Random, count: int, folder: Path) -> dict[str, Counter]:
    """Damaged copies of finished runs through eval, resume and render: accepted only with the output the
    undamaged run gives (eval's measurement, resume's "complete", render's episode), else a silent acceptance."""
    finished, others = {}, {}
    for kind, extra in (
        ("model-free", ["--budget", "24"]),
        ("model-based", ["--model-based", "--budget", "4", "--generations-per-iteration", "2", "--model-hidden", "8"]),
    ):
        for seed, made in (("0", finished), ("1", others)):
            made[kind] = folder / f"{kind}-{seed}"
            result = CliRunner().invoke(
                main,
                [
                    "train",
                    "cartpole",
                    *extra,
                    "--eval-episodes",
                    "3",
                    "--seed",
                    seed,
                    "--quiet",
                    "--out",
                    str(made[kind]),
                ],
            )
            assert result.exit_code == 0, result.output
    video = folder / "video.gif"
    args = {
        "eval": lambda run: ["eval", str(run), "--episodes", "3"],
        "resume": lambda run: ["train", "--resume", str(run), "--quiet"],
        "render": lambda run: ["render", str(run), "--out", str(video), "--max-steps", "5"],
    }
    expected = {
        (kind, name): CliRunner().invoke(main, make(run)).output.replace(str(run), "RUN")
        for kind, run in finished.items()
        for name, make in args.items()
    }
    results = {name: Counter() for name in args}
    for number in range(count):
        kind = rng.choice(list(finished))
        for name, make in args.items():
            run = folder / f"damaged{number}-{name}"
            shutil.copytree(finished[kind], run)
            what = damage(random.Random(number), run, others[kind])  # the same damage for the three commands
            got = command(make(run), run, expected[kind, name])
            results[name][f"{got}: {what}" if got.startswith("silent") else got] += 1
            shutil.rmtree(run, ignore_errors=True)
    return results


def table(name: str, results: Counter) -> None:
    tried = sum(results.values())
    defects = {key: value for key, value in results.items() if key.startswith(("traceback", "silent"))}
    print(
        f"| {name} | {tried} | {results['accepted']} | {results['refused']} | "
        f"{sum(v for k, v in defects.items() if k.startswith('traceback'))} | "
        f"{sum(v for k, v in defects.items() if k.startswith('silent'))} |"
    )
    for key, value in sorted(defects.items(), key=lambda item: -item[1])[:5]:
        print(f"|   {value} × {key[:150]} | | | | | |")


def main_() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settings", type=int, default=3000)
    parser.add_argument("--files", type=int, default=2000)
    parser.add_argument("--folders", type=int, default=300)
    parser.add_argument("--flags", type=int, default=1000)
    parser.add_argument("--places", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    folder = Path(tempfile.mkdtemp(prefix="drrl-adversarial-"))
    print("| inputs | tried | accepted | refused cleanly | tracebacks | silent acceptances |")
    print("| --- | --- | --- | --- | --- | --- |")
    table("generated settings (validated, prepared)", sweep_settings(rng, args.settings))
    table("damaged config files (drrl train --config)", sweep_files(rng, args.files, folder))
    for name, results in sweep_folders(rng, args.folders, folder).items():
        table(f"damaged run folders: drrl {name}", results)
    for name, results in sweep_flags(rng, args.flags, folder).items():
        table(f"flags of drrl {name}", results)
    table("places to write (train --out, render --out)", sweep_places(rng, args.places, folder))
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main_()
