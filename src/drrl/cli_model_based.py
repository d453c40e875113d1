"""The model-based parts of the ``drrl`` command: ``drrl train --model-based`` options and ``drrl compare``.

Kept beside ``drrl.cli`` so that the command's main module stays small; ``drrl.cli`` adds these to its commands.
"""

from __future__ import annotations

import time
from pathlib import Path

import click
from pydantic import ValidationError

from drrl.cli_params import INTEGER
from drrl.compare import DEFAULT_METHODS, METHODS, MODEL_BASED, PPO, compare, curve_budget, method_config
from drrl.config import describe_errors, env_defaults, load_config_file
from drrl.envs.batch import is_frames, make_batch_env
from drrl.models.kinds import MODEL_KINDS
from drrl.models.settings import MODEL_BASED_DEFAULTS, ModelBasedSettings

COMPARE_BUDGET = 300  # real episodes of a model-free run in a comparison: enough for the cart-pole's PGPE to balance

# option name -> ModelBasedSettings field
MODEL_OPTIONS = {
    "model_kind": "model_kind",
    "model_hidden": "hidden",
    "overshoot": "overshoot",
    "ensemble": "ensemble_size",
    "generations": "generations",
    "policy_memory": "policy_memory",
}


def _default(field: str):
    return ModelBasedSettings.model_fields[field].default


def model_based_options(command):
    """``--model-based`` and the options of the world model, for ``drrl train``."""
    options = [
        click.option(
            "--model-based",
            is_flag=True,
            help="Model-based PGPE: fit a recurrent world model to real "
            f"episodes and search in it. Its defaults: {MODEL_BASED_DEFAULTS}; popsize and "
            "episodes-per-candidate then count imagined episodes.",
        ),
        click.option(
            "--model-kind",
            type=click.Choice(MODEL_KINDS),
            help="world model: state-space RNN (3.4), LSTM (3.5.2), their layers without memory (mlp), or linear "
            "or sparse polynomial, fitted by least squares  "
            f"[default: {_default('model_kind')}]",
        ),
        click.option(
            "--model-hidden", metavar="W[,W...]", help="widths of the world model's stacked layers  [default: 64]"
        ),
        click.option(
            "--overshoot", type=INTEGER, help=f"overshooting steps (3.3.2)  [default: {_default('overshoot')}]"
        ),
        click.option(
            "--ensemble", type=INTEGER, help=f"world models in the ensemble  [default: {_default('ensemble_size')}]"
        ),
        click.option(
            "--generations",
            type=INTEGER,
            help=f"most PGPE generations in the model per iteration  [default: {_default('generations')}]",
        ),
        click.option(
            "--policy-memory",
            is_flag=True,
            default=None,
            help="the policy also reads the world model's memory (its hidden state), as World Models' controller "
            "does: for frames and partially observed tasks",
        ),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def pop_model_options(options: dict) -> dict:
    """Take the world-model options out of ``options`` (given ones only), as ModelBasedSettings fields."""
    taken = {MODEL_OPTIONS[name]: options.pop(name) for name in list(options) if name in MODEL_OPTIONS}
    given = {field: value for field, value in taken.items() if value is not None}
    if "hidden" in given:
        try:
            given["hidden"] = tuple(int(width) for width in given["hidden"].split(","))
        except ValueError:
            raise click.UsageError(
                f"--model-hidden: {given['hidden']!r} is not a comma-separated list of layer widths such as 64 or 64,64"
            ) from None
    return given


def with_model_based(settings: dict, model_based: bool, model_options: dict) -> dict:
    """``settings`` with the world-model options under ``model_based`` (TrainConfig then starts the fields left unset
    from the model-based defaults). Unchanged for a model-free run, which must not get world-model options."""
    table = settings.get("model_based")
    if table is not None and not isinstance(table, dict):
        return settings  # TrainConfig says what model_based must be
    model_based = model_based or table is not None
    if not model_based:
        if model_options:
            names = ", ".join(
                f"--{name.replace('_', '-')}" for name in MODEL_OPTIONS if MODEL_OPTIONS[name] in model_options
            )
            raise click.UsageError(f"{names} only apply to a model-based run; add --model-based")
        return settings
    return {**settings, "model_based": {**(settings.get("model_based") or {}), **model_options}}


def observes_frames(env: str) -> bool:
    """Whether ``env`` observes frames (``drrl.envs.pixels``); an env that cannot be made is refused in one line."""
    try:
        probe = make_batch_env(env, 1)
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    frames = is_frames(probe.single_observation_space)
    probe.close()
    return frames


@click.command("compare")
@click.option("--env", default="cartpole", show_default=True, help="Environment to compare the methods on.")
@click.option("--seeds", type=click.IntRange(min=1), default=3, show_default=True, help="seeds per method")
@click.option(
    "--budget",
    type=click.IntRange(min=1),
    help="real training episodes of each model-free run (PGPE, REINFORCE, eNAC, PPO)  "
    f"[default: {COMPARE_BUDGET}, or the env's own budget where it has one, one attempt's where its runs restart]",
)
@click.option(
    "--model-based-budget",
    type=click.IntRange(min=1),
    help="real training episodes of each model-based run  "
    f"[default: {MODEL_BASED_DEFAULTS['budget']}, or the env's own model-based budget]",
)
@click.option(
    "--method",
    "methods",
    type=click.Choice(METHODS),
    multiple=True,
    help="methods to run (repeat the option)  [default: all but PPO, which needs the sb3 extra]",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML or JSON file of settings for every run (its model_based table for the model-based one)",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("compare"),
    show_default=True,
    help="folder for compare.png and compare.csv",
)
def compare_command(env, seeds, budget, model_based_budget, methods, config_file, out) -> None:
    """Figure 5.2 extended: the centre's average return against real training episodes for REINFORCE-, SyS-,
    super-symmetric and model-based PGPE and the action-space REINFORCE and eNAC (and PPO, if asked), mean and
    ±1 s.e. band over seeds, as one PNG and one CSV."""
    try:
        settings = load_config_file(config_file) if config_file else {}
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    settings["env"] = env
    if budget is None:
        budget = curve_budget(env, COMPARE_BUDGET)
    if model_based_budget is None:
        model_based_budget = env_defaults(env, model_based=True).get("budget", MODEL_BASED_DEFAULTS["budget"])
    frames = observes_frames(env)
    methods = methods or ((MODEL_BASED,) if frames else DEFAULT_METHODS)
    if frames and set(methods) != {MODEL_BASED}:
        raise click.UsageError(
            f"{env} observes frames, which only {MODEL_BASED!r} learns from (it encodes them); use "
            f"--method {MODEL_BASED!r}"
        )
    try:  # every method's config is checked before any run starts
        for method in methods:
            if method != PPO:
                method_config(method, 0, model_based_budget if method == MODEL_BASED else budget, settings)
    except ValidationError as error:
        raise click.UsageError("invalid configuration:\n" + describe_errors(error)) from None
    start = time.perf_counter()

    def progress(method, seed, run):
        click.echo(
            f"{method}, seed {seed}: centre's return {run[-1][1]:.1f} after {run[-1][0]} real episodes "
            f"({time.perf_counter() - start:.0f} s)"
        )

    try:
        compare(out, seeds, budget, model_based_budget, settings, methods, progress)
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    click.echo(f"wrote {out / 'compare.png'} and {out / 'compare.csv'}")
