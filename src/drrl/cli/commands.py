"""The ``drrl`` command: ``drrl train`` and ``drrl eval``."""

from __future__ import annotations

import datetime
import traceback
from pathlib import Path

import click
from pydantic import ValidationError

from drrl import __version__
from drrl.cli.compare import compare_command
from drrl.cli.params import COUNT, EPISODES, SEED, AsciiInt
from drrl.cli.settings import FLAGS, given_settings, settings_options, with_file, with_run_kind
from drrl.cli.settings import show_settings as show_settings_of
from drrl.envs.batch import make_batch_env
from drrl.envs.gymnasium_tasks import alive_bonus_note
from drrl.envs.registry import aliases, is_own, lookup
from drrl.rollout import BACKENDS, NonFiniteOutput
from drrl.runs import RunFolder, check_writable
from drrl.settings import TrainConfig, describe_errors, load_config_file
from drrl.settings.flat import flattened
from drrl.settings.presets import not_learned, task_preset, task_settings
from drrl.streams import Stream, derive_seed
from drrl.training.loop import Counters, Setup, measure, one_thread, run, sigterm_as_interrupt, solved
from drrl.training.model_based import ModelDiverged
from drrl.training.train import (
    as_read,
    build_policy,
    check_same_spaces,
    open_run,
    prepare,
    prepare_resume,
    subscribers,
    trained_center,
)

ERROR_LOG = "error.log"  # in the run folder: the traceback of whatever stopped the run


class Commands(click.Group):
    """drrl's commands: a refusal is one line; with --debug (or DRRL_DEBUG=1) the traceback behind it too."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except click.ClickException as error:
            if ctx.meta.get("debug") and error.__context__ is not None:
                traceback.print_exception(error.__context__)
            raise


@click.group(cls=Commands)
@click.version_option(__version__, prog_name="drrl")
@click.option("--debug", is_flag=True, envvar="DRRL_DEBUG", help="show the traceback behind an error message")
@click.pass_context
def main(ctx: click.Context, debug: bool) -> None:
    """Sample-efficient robot reinforcement learning: PGPE over neural-network policies."""
    ctx.meta["debug"] = debug


@main.command("train")
@click.argument("env_name", required=False, metavar="[ENV]")
@click.option(
    "--env",
    "env_option",
    help=f"the environment, the same as ENV (give one): {', '.join(aliases())}, any Gymnasium id (e.g. Pendulum-v1) "
    "or MODULE:ID for an env that registers itself when MODULE is imported  [default: cartpole]",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML or JSON file of settings; command-line options override it.",
)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), help="run folder  [default: runs/ENV-TIME]")
@click.option("--quiet", is_flag=True, help="no progress bar")
@click.option(
    "--resume",
    "resume_path",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    metavar="RUN",
    help="continue the stopped run RUN from its checkpoint, with its own settings",
)
@click.option(
    "--backend",
    type=click.Choice(BACKENDS),
    default="local",
    show_default=True,
    help='where candidates are evaluated: this process, or Ray actors (pip install "drrl[ray]")',
)
@click.option("--address", help="Ray cluster to join, e.g. 10.0.0.1:6379  [default: start a local Ray]")
@click.option("--workers", type=COUNT, help="Ray actors  [default: one per CPU of the cluster]")
@click.option(
    "--tensorboard",
    is_flag=True,
    help='also log every metric for TensorBoard into RUN/tensorboard (pip install "drrl[tensorboard]")',
)
@settings_options
def train_command(
    env_name,
    env_option,
    config_file,
    out,
    quiet,
    resume_path,
    backend,
    address,
    workers,
    tensorboard,
    model_based,
    assignments,
    show_settings,
    **options,
) -> None:
    """Train a policy on ENV (a drrl task, a Gymnasium id or MODULE:ID; --env names it too): `drrl train cartpole`,
    model-based with `--model-based`; `drrl train --resume RUN` continues a stopped run."""
    if resume_path is not None:
        given = [
            name
            for name, value in [
                ("ENV", env_name),
                ("--env", env_option),
                ("--config", config_file),
                ("--out", out),
                ("--model-based" if model_based else "--model-free", model_based),
                ("--set", assignments),
                *((FLAGS.get(key.replace("__", "."), "--search"), value) for key, value in options.items()),
            ]
            if value is not None and value != ()
        ]
        if given:
            raise click.UsageError(
                f"--resume continues RUN with the settings in its config.json; drop {', '.join(given)}"
            )
        return resume_run(resume_path, backend, address, workers, quiet, tensorboard)
    if env_name and env_option and env_name != env_option:
        raise click.UsageError(f"two environments given: {env_name!r} and --env {env_option!r}")
    try:
        file_settings = load_config_file(config_file) if config_file else {}
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    flags = given_settings(options, assignments)
    if env_name is not None or env_option is not None:
        flags["env"] = env_name if env_name is not None else env_option
    flags = with_run_kind(file_settings, flags, model_based)
    settings = with_file(file_settings, flags)
    try:
        config = TrainConfig.model_validate(settings)
    except ValidationError as error:
        raise click.UsageError("invalid configuration:\n" + describe_errors(error)) from None
    if show_settings:
        return click.echo(show_settings_of(config, config_file, file_settings, flags))
    try:
        lookup(config.env)  # an unknown env is refused before a folder is named after it
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    if (warning := not_learned(config.env)) is not None:
        click.echo(f"note: {warning}", err=True)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out or Path("runs") / f"{config.env.replace('/', '-')[:100]}-{stamp}")
    with sigterm_as_interrupt():  # from before the folder exists: a signal finds it whole or absent
        start_run(config, out, backend, address, workers, quiet, tensorboard)


def start_run(
    config: TrainConfig,
    out: Path,
    backend: str,
    address: str | None,
    workers: int | None,
    quiet: bool,
    tensorboard: bool,
) -> None:
    """Make the run folder, prepare the run (an interrupt meanwhile leaves no folder behind), then run it."""
    try:  # before any work (demonstrations are recorded while preparing): an occupied --out is refused at once
        check_writable(out, "run folder", folder=True)
        made = not out.exists()
        folder = RunFolder.create(out)
    except ValueError as error:
        raise click.UsageError(str(error)) from None
    setup = None
    try:
        setup = prepare(config, backend, address, workers, progress=not quiet)
        attached = subscribers(folder, not quiet, tensorboard)
    except (ValueError, ImportError, KeyboardInterrupt) as error:  # a bad env, conflicting settings, no TensorBoard
        if setup is not None:
            setup.close()
        abandon(folder, made)
        if isinstance(error, KeyboardInterrupt):
            raise click.ClickException("interrupted while preparing the run; nothing was trained") from None
        raise click.UsageError(str(error)) from None
    run_and_report(setup, folder, attached)


def abandon(folder: RunFolder, made: bool) -> None:
    """Let go of a run folder no run started in, and remove it if this command made it and it is still empty."""
    folder.release()
    if made and not any(folder.path.iterdir()):
        folder.path.rmdir()


def resume_run(
    path: Path, backend: str, address: str | None, workers: int | None, quiet: bool, tensorboard: bool
) -> None:
    """`drrl train --resume RUN`: the run rebuilt at its checkpoint, metrics past it dropped, then continued."""
    folder = RunFolder(path)
    try:
        setup, counters = prepare_resume(folder, backend, address, workers)
    except ValueError as error:
        raise click.ClickException(f"cannot resume {path}: {error}") from None
    unit, total = setup.world.unit, setup.world.iterations
    if counters is not None and counters.iteration == total:
        setup.close()
        return click.echo(f"{path} is complete: all {total} {unit}s done")
    try:
        attached = subscribers(folder, not quiet, tensorboard)
    except ImportError as error:
        setup.close()
        raise click.UsageError(str(error)) from None
    if counters is None:
        click.echo(f"starting {path} again from its start: it stopped before its first checkpoint")
    else:
        click.echo(f"resuming {path} at {unit} {counters.iteration + 1} of {total}")
    run_and_report(setup, folder, attached, counters)


LARGER_POLICIES = ("mlp:32", "mlp:64,64")


def generic_advice(kind: str, policy: str) -> str:
    """What most often helps a run of ``kind`` (``World.kind``) that missed, less the policy it already had."""
    larger = [spec for spec in LARGER_POLICIES if spec != policy]
    policies = f"a larger --policy ({', '.join(larger)})" if larger else "a larger --policy"
    return {
        "model-free": f"try a larger --budget, more --episodes-per-candidate, another --sigma-init or {policies}",
        "model-based": "try a larger --budget (real episodes), more --generations-per-iteration in the model, or "
        "another world model (--model-kind, --model-hidden, --ensemble 5)",
        "action-space": f"try a larger --budget, another --center-lr (its step size) or {policies}",
    }[kind]


def overridden_defaults(setup: Setup) -> dict:
    """The env's own preset settings (model-free or model-based, as the run) that the run set otherwise, the model's
    own table aside: what to go back to after a miss."""
    kind = "model-based" if setup.config.model_based else "model-free"
    flat = flattened(setup.config)
    return {
        name: value
        for name, value in task_settings(setup.config.env, kind).items()
        if name != "model_based" and flat.get(name) != value
    }


def advice_after_a_miss(setup: Setup) -> str:
    """What to try after a run whose centre met none of the task's criteria: the task's own settings the run set
    otherwise, or with none, what most often helps a run of its kind (never a setting the run already had); after a
    model-free run, a model-based one where drrl has model-based settings for the env."""
    suggested = overridden_defaults(setup)
    advice = generic_advice(setup.world.kind, setup.config.policy)
    if suggested:
        advice = "settings that suit it: " + " ".join(
            f"--{name.replace('_', '-')} {value}" for name, value in suggested.items()
        )
    if setup.world.kind == "model-free" and task_preset(setup.entry.env_id, "model-based"):
        advice += f"; or model-based, with settings measured on it: drrl train {setup.entry.env_id} --model-based"
    return advice


def verdict_of_best(setup: Setup, counters: Counters) -> str | None:
    """The verdict on the best measured centre, in words: which of the task's criteria it met when measured."""
    unit, criteria = setup.world.unit, setup.entry.criteria()
    row = next((row for row in counters.rows if int(float(row.get(unit, -1))) == counters.best_iteration), None)
    if row is None or not criteria:
        return None
    met = [name.replace("_", "-") for name in criteria if float(row.get(name, 0)) == 1]
    missed = [name.replace("_", "-") for name in criteria if float(row.get(name, 0)) != 1]
    said = " and ".join(met) + (f", not {' or '.join(missed)}" if missed else "")
    return (
        f"the best measured centre was {said} on its {setup.eval_env.num_envs} measuring episodes; "
        "drrl eval measures it again on fresh ones"
    )


def run_and_report(setup: Setup, folder: RunFolder, attached: list, counters: Counters | None = None) -> None:
    """Run the training loop, then say what it did; a stopped run says how to resume it."""
    out, unit = folder.path, setup.world.unit
    try:
        counters = run(setup, attached, counters)
    except (NonFiniteOutput, ModelDiverged, KeyboardInterrupt) as error:
        why = "interrupted" if isinstance(error, KeyboardInterrupt) else str(error)
        if not isinstance(error, KeyboardInterrupt):
            (out / ERROR_LOG).write_text(traceback.format_exc())
        if folder.stopped_before_its_first_checkpoint():
            raise click.ClickException(
                f"{why} before the first checkpoint\nrun folder kept: {out}\nstart it again with: drrl train "
                f"--resume {out}"
            ) from None
        done = folder.load_checkpoint()["iteration"]
        raise click.ClickException(
            f"{why}\nrun folder and checkpoint ({unit} {done}) kept: {out}\ncontinue with: drrl train --resume {out}"
        ) from None
    except OSError as error:  # a full disk, a folder removed under the run: what was written before is kept
        raise click.ClickException(
            f"cannot write {error.filename or 'to the run folder'}: {error.strerror or error}; "
            f"{out} keeps what was written before; free space, then: drrl train --resume "
            f"{out}"
        ) from None
    except Exception:  # not a user's mistake: the traceback shows, and the run folder keeps it
        (out / ERROR_LOG).write_text(traceback.format_exc())
        raise
    imagined = (
        f" ({counters.imagined_episodes} imagined episodes, {counters.imagined_steps} imagined steps apart)"
        if counters.imagined_episodes
        else ""
    )
    if solved(setup, counters):
        why = (
            "stop_when_solved"
            if setup.config.measuring.stop_when_solved
            else f"the end of attempt {counters.rows[-1]['attempt']}"
        )
        click.echo(
            f"solved: the centre of {unit} {counters.iteration} met every criterion of {setup.entry.env_id}; the run "
            f"stopped there ({why}), {setup.world.real_budget - counters.real_episodes} real episodes of the budget "
            f"unspent"
        )
    click.echo(
        f"done: {counters.iteration} {unit}{'s' * (counters.iteration != 1)}, {counters.real_episodes} real episodes, "
        f"{counters.real_steps} real steps{imagined}; best measured centre {counters.best_center_return:.1f} "
        f"({unit} {counters.best_iteration}), what drrl eval runs; the last {counters.rows[-1]['center_return']:.1f}"
    )
    if counters.best_center_criteria and (verdict := verdict_of_best(setup, counters)):
        click.echo(verdict)
    if setup.entry.criteria() and not counters.best_center_criteria:
        click.echo(
            f"the centre met none of {setup.entry.env_id}'s criteria ({', '.join(setup.entry.criteria())}); "
            f"{advice_after_a_miss(setup)}"
        )
    click.echo(f"run folder: {out} (metrics.csv, learning_curve.png, checkpoint.safetensors)")
    click.echo(f"next: drrl eval {out}")


@main.command("eval")
@click.argument("run_path", metavar="RUN", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--episodes", type=EPISODES, default=50, show_default=True, help="fresh episodes to measure")
@click.option("--seed", type=SEED, default=0, show_default=True, help="the first episode's reset seed")
@click.option("--final", is_flag=True, help="the last centre policy instead of the best measured one")
@click.option(
    "--env",
    "env_name",
    help="measure on this env instead of the run's (same spaces), e.g. baxter-reach-right-standin",
)
def eval_command(run_path: Path, episodes: int, seed: int, final: bool, env_name: str | None) -> None:
    """Run a trained centre policy over fresh episodes and report how it does.

    By default the centre policy that measured best during training; its measurement chose it, so it is measured
    again here on new episodes. `--env` measures it on another env with the same spaces: how it transfers.
    """
    run = RunFolder(run_path)
    try:
        config, checkpoint = open_run(run)
        entry = lookup(checkpoint["env_id"] if env_name is None else env_name)
        env = make_batch_env(entry.env_id, episodes, config.engine if env_name is None else "auto")
        if env_name is not None:
            trained_on = make_batch_env(checkpoint["env_id"], 1, config.engine)
            trained_on.close()
            check_same_spaces(
                checkpoint["env_id"],
                (trained_on.single_observation_space, trained_on.single_action_space),
                entry.env_id,
                (env.single_observation_space, env.single_action_space),
            )
    except ValueError as error:
        raise click.ClickException(f"{run_path}: {error}") from None
    policy = build_policy(config, env)
    try:
        center = trained_center(checkpoint, policy, final)
        seen = as_read(config, checkpoint, env)
    except ValueError as error:
        env.close()
        raise click.ClickException(f"{run_path}: {error}") from None
    step = checkpoint["iteration"] if final else checkpoint["best_iteration"]
    which = f"{'final' if final else 'best measured'} centre ({checkpoint.get('unit', 'generation')} {step})"
    with one_thread():
        result = measure(policy, center, seen, config.max_steps, derive_seed(seed, 0, Stream.EVALUATING))
    env.close()
    returns = result.episode_returns.flatten().numpy()
    click.echo(
        f"{entry.env_id}, {config.policy} policy, {which}, {episodes} episodes: return "
        f"{returns.mean():.1f} ± {returns.std():.1f} (min {returns.min():.1f}, max {returns.max():.1f})"
    )
    verdict = entry.judge(result.episode_returns, result.terminated)
    for name, ok in verdict.items():
        click.echo(f"{name.replace('_', '-') + ':':14}{'yes' if ok else 'no'}")
    if not verdict:
        why = (
            "its shaped reward has no level; the same task with a sparse reward has a verdict (drrl eval RUN --env "
            "TASK measures this policy there)"
            if is_own(entry.env_id)
            else "it has no reward_threshold and drrl knows no level for it: set the return beside a published one"
        )
        click.echo(f"verdict:      none ({why})")
    if entry.explain is not None:
        click.echo(entry.explain(result.episode_returns, result.terminated))
    farming = alive_bonus_note(entry.env_id, result.episode_returns, result.episode_steps)
    if farming is not None:
        click.echo(farming)


@main.command("render")
@click.argument("run_path", metavar="RUN", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=Path("episode.gif"),
    show_default=True,
    help="video file: .gif, or .mp4 (needs drrl[render])",
)
@click.option("--seed", type=SEED, default=0, show_default=True, help="the episode's reset seed")
@click.option("--final", is_flag=True, help="the last centre policy instead of the best measured one")
@click.option("--fps", type=AsciiInt(1, 1000), default=25, show_default=True, help="video frames per second")
@click.option("--max-steps", type=COUNT, help="stop the episode after this many steps")
@click.option("--shadows", is_flag=True, help="Baxter: MuJoCo's shadows and reflections (about 5× slower)")
@click.option("--env", "env_name", help="record on this env instead, of the same spaces (e.g. a stand-in robot)")
def render_command(
    run_path: Path,
    out: Path,
    seed: int,
    final: bool,
    fps: int,
    max_steps: int | None,
    shadows: bool,
    env_name: str | None,
) -> None:
    """Record one episode of a trained centre policy as a video, headless, e.g. `drrl render RUN --out reach.mp4`."""
    from drrl.video import render_run  # imports Pillow and, for Baxter, MuJoCo's renderer only when asked

    try:
        recording = render_run(
            run_path,
            out,
            final=final,
            seed=seed,
            fps=fps,
            max_steps=max_steps,
            env_name=env_name,
            **({"shadows": True} if shadows else {}),
        )
    except (ValueError, ImportError, RuntimeError) as error:  # a bad run folder or format, no MP4 writer or GL
        raise click.ClickException(str(error)) from None
    distance = recording.info.get("distance")
    click.echo(
        f"wrote {out}: {len(recording.frames)} frames at {recording.fps:g} fps; {recording.steps} steps, "
        f"return {recording.episode_return:.1f}"
        + ("" if distance is None else f", final end-point distance {float(distance):.3f} m")
    )


main.add_command(compare_command)
