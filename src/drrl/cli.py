"""The ``drrl`` command: ``drrl train`` and ``drrl eval``."""

from __future__ import annotations

import datetime
from pathlib import Path

import click
from pydantic import ValidationError

from drrl import __version__
from drrl.config import TrainConfig, describe_errors, load_config_file
from drrl.envs.batch import make_batch_env
from drrl.envs.solved import VERDICTS
from drrl.runs import RunFolder
from drrl.search.pgpe import FITNESS_SHAPINGS, OPTIMIZERS, SAMPLERS
from drrl.train import NonFiniteReturn, build_policy, derive_seed, measure, train

EVAL_STREAM = 2  # episode seeds of `drrl eval`, apart from training's and measuring's


@click.group()
@click.version_option(__version__, prog_name="drrl")
def main() -> None:
    """Sample-efficient robot reinforcement learning: PGPE over neural-network policies."""


@main.command("train")
@click.argument("env_name", required=False, metavar="[ENV]")
@click.option("--env", "env_option", help="Environment: cartpole or any Gymnasium id (e.g. Pendulum-v1).")
@click.option("--policy", help="linear, linear:nobias, multilinear:W[,W...], mlp:W[,W...]  [default: linear]")
@click.option("--sampler", type=click.Choice(SAMPLERS), help="PGPE sampler  [default: symmetric]")
@click.option("--optimizer", type=click.Choice(OPTIMIZERS), help="step rule for μ  [default: sgd]")
@click.option("--fitness-shaping", type=click.Choice(FITNESS_SHAPINGS), help="[default: none]")
@click.option("--popsize", type=int, help="candidates per generation  [default: 10]")
@click.option("--episodes-per-candidate", type=int, help="real episodes per candidate  [default: 1]")
@click.option("--budget", type=int, help="real training episodes to spend  [default: 1000]")
@click.option("--sigma-init", type=float, help="initial σ of every parameter")
@click.option("--center-lr", type=float, help="learning rate of μ")
@click.option("--sigma-lr", type=float, help="learning rate of σ")
@click.option("--eval-episodes", type=int, help="episodes measuring the centre policy  [default: 50]")
@click.option("--eval-every", type=int, help="generations between measurements  [default: 1]")
@click.option("--seed", type=int, help="[default: 0]")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path),
              help="TOML or JSON file of settings; command-line options override it.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), help="run folder  [default: runs/ENV-TIME]")
@click.option("--quiet", is_flag=True, help="no progress bar")
def train_command(env_name, env_option, config_file, out, quiet, **options) -> None:
    """Train a policy with PGPE, e.g. `drrl train cartpole`."""
    if env_name and env_option and env_name != env_option:
        raise click.UsageError(f"two environments given: {env_name!r} and --env {env_option!r}")
    settings = load_config_file(config_file) if config_file else {}
    if env_name or env_option:
        settings["env"] = env_name or env_option
    settings.update({key: value for key, value in options.items() if value is not None})
    try:
        config = TrainConfig.model_validate(settings)
    except ValidationError as error:
        raise click.UsageError("invalid configuration:\n" + describe_errors(error)) from None
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    run = RunFolder.create(out or Path("runs") / f"{config.env.replace('/', '-')}-{stamp}")
    click.echo(f"run folder: {run.path}")
    try:
        counters = train(config, run, progress=not quiet)
    except NonFiniteReturn as error:
        raise click.ClickException(f"{error}\nrun folder kept: {run.path}") from None
    except KeyboardInterrupt:
        raise click.ClickException(f"interrupted; run folder and checkpoint kept: {run.path}") from None
    row = counters.rows[-1]
    click.echo(f"done: {counters.generation} generations, "
               f"{counters.real_episodes} real episodes, {counters.real_steps} real steps; "
               f"centre return {row['center_return']:.1f}")
    click.echo(f"metrics: {run.path / 'metrics.csv'}, learning curve: {run.path / 'learning_curve.png'}")


@main.command("eval")
@click.argument("run_path", metavar="RUN", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--episodes", type=click.IntRange(min=1), default=50, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
def eval_command(run_path: Path, episodes: int, seed: int) -> None:
    """Run a trained centre policy over fresh episodes and report how it does."""
    run = RunFolder(run_path)
    try:
        config = run.read_config()
        checkpoint = run.load_checkpoint()
    except ValueError as error:
        raise click.ClickException(str(error)) from None
    env = make_batch_env(checkpoint["env_id"], episodes)
    policy = build_policy(config, env)
    result = measure(policy, checkpoint["center"], env, config, derive_seed(seed, 0, EVAL_STREAM))
    env.close()
    returns = result.episode_returns.flatten().numpy()
    click.echo(f"{checkpoint['env_id']}, {config.policy} policy, {episodes} episodes: return "
               f"{returns.mean():.1f} ± {returns.std():.1f} (min {returns.min():.1f}, max {returns.max():.1f})")
    verdict = VERDICTS.get(checkpoint["env_id"])
    if verdict is not None:
        kept = int((~result.terminated).sum())
        for name, ok in verdict(result.episode_returns, result.terminated).items():
            click.echo(f"{name.replace('_', '-') + ':':14}{'yes' if ok else 'no'}")
        click.echo(f"({kept}/{episodes} episodes kept the pole up for all 200 steps; near-optimal needs a mean "
                   f"return ≥ -50)")
