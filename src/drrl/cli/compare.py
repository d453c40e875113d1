"""``drrl compare``: the methods side by side on one task, kept beside ``drrl.cli``, which adds it to its commands."""

from __future__ import annotations

import time
from pathlib import Path

import click
from pydantic import ValidationError

from drrl.cli.params import COUNT
from drrl.compare import (
    DEFAULT_METHODS,
    METHODS,
    MODEL_BASED,
    PPO,
    compare,
    curve_budget,
    method_config,
    model_based_budget_of,
)
from drrl.envs.batch import is_frames, make_batch_env
from drrl.runs import check_writable
from drrl.settings import describe_errors, load_config_file, short_repr

COMPARE_BUDGET = 300  # real episodes of a model-free run in a comparison: enough for the cart-pole's PGPE to balance


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
@click.option("--env", help="Environment to compare the methods on  [default: the config file's env, else cartpole]")
@click.option("--seeds", type=COUNT, default=3, show_default=True, help="seeds per method")
@click.option(
    "--budget",
    type=COUNT,
    help="real training episodes of each model-free run (PGPE, REINFORCE, eNAC, PPO)  "
    f"[default: {COMPARE_BUDGET}, or the env's own budget where it has one, one attempt's where its runs restart]",
)
@click.option(
    "--model-based-budget",
    type=COUNT,
    help="real training episodes of each model-based run  "
    "[default: a model-based run's on the env, as drrl train --model-based spends]",
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
        check_writable(out, "compare folder", folder=True)
        settings = load_config_file(config_file) if config_file else {}
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    if env is not None and settings.get("env", env) != env:
        raise click.UsageError(f"two environments given: {settings['env']!r} in {config_file} and --env {env!r}")
    env = settings["env"] = env or settings.get("env") or "cartpole"
    if not isinstance(env, str):
        raise click.UsageError(f"env in {config_file}: must be an environment name, not {short_repr(env)}")
    if budget is None:
        budget = curve_budget(env, COMPARE_BUDGET)
    if model_based_budget is None:
        model_based_budget = model_based_budget_of(env)
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
