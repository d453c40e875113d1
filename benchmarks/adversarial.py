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
import random
import shutil
import tempfile
import traceback
from collections import Counter
from pathlib import Path

from click.testing import CliRunner
from pydantic import ValidationError

from drrl.cli import main
from drrl.runs import CHECKPOINT, CONFIG, METRICS
from drrl.settings import TrainConfig, describe_errors, load_config_file
from drrl.training.train import prepare

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


def damage(rng: random.Random, run: Path) -> str:
    """One random damage to ``run``; its name."""
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
            tensors = {key: handle.get_tensor(key) for key in handle}
            metadata = handle.metadata()
        metadata["sha257"] = metadata.pop("sha256")
        save_file(tensors, checkpoint, metadata=metadata)
    elif kind == "remove file":
        (run / rng.choice([CHECKPOINT, CONFIG, METRICS])).unlink()
    else:
        lines = (run / METRICS).read_text().splitlines(keepends=True)
        (run / METRICS).write_text("".join(lines[: rng.randrange(len(lines))]))
    return kind


def command(args: list[str]) -> str:
    result = CliRunner().invoke(main, args)
    if result.exit_code == 0:
        return "accepted"
    if isinstance(result.exception, SystemExit) and "Traceback" not in result.output:
        return "refused"
    text = "".join(traceback.format_exception(result.exception))[-200:] if result.exception else result.output
    return f"traceback: {text!r}"


def unchanged(original: Path, damaged: Path, read: tuple[str, ...]) -> bool:
    """Whether the damage left the files a command reads (``read``) meaning what they meant: the same config
    values, the same checkpoint and metrics bytes."""

    def meaning(run: Path, name: str):
        data = (run / name).read_bytes()
        try:
            return json.loads(data) if name == CONFIG else data
        except ValueError:
            return data

    return all((damaged / name).exists() and meaning(original, name) == meaning(damaged, name) for name in read)


def sweep_folders(rng: random.Random, count: int, folder: Path) -> dict[str, Counter]:
    finished = {}
    for kind, extra in (
        ("model-free", ["--budget", "24"]),
        ("model-based", ["--model-based", "--budget", "4", "--generations-per-iteration", "2", "--model-hidden", "8"]),
    ):
        finished[kind] = folder / kind
        result = CliRunner().invoke(
            main, ["train", "cartpole", *extra, "--eval-episodes", "3", "--quiet", "--out", str(finished[kind])]
        )
        assert result.exit_code == 0, result.output
    results = {name: Counter() for name in ("eval", "resume", "render")}
    for number in range(count):
        kind = rng.choice(list(finished))
        for name in results:
            run = folder / f"damaged{number}-{name}"
            shutil.copytree(finished[kind], run)
            rng_copy = random.Random(number)  # the same damage for the three commands
            what = damage(rng_copy, run)
            args = {
                "eval": ["eval", str(run), "--episodes", "3"],
                "resume": ["train", "--resume", str(run), "--quiet"],
                "render": ["render", str(run), "--out", str(folder / f"video{number}.gif"), "--max-steps", "5"],
            }
            got = command(args[name])
            read = (CONFIG, CHECKPOINT, METRICS) if name == "resume" else (CONFIG, CHECKPOINT)
            if got == "accepted" and not unchanged(finished[kind], run, read):
                got = f"silent acceptance: {what}"
            results[name][got] += 1
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
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main_()
