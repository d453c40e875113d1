"""``drrl train``'s settings options, drawn from the settings schema: one option per flat setting
(``drrl.settings.flat``) with the field's own description, ``--set NAME=VALUE`` for any setting, and
``--show-settings``."""

from __future__ import annotations

import tomllib
import typing
from pathlib import Path

import click
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from drrl.cli.params import INTEGER
from drrl.settings import TrainConfig
from drrl.settings.flat import FLAT, SEARCH_DESCRIPTION, TABLE, FlatSetting, flattened, layers_for, merged
from drrl.settings.parts import PARAMETER_SEARCHES, POLICY_GRADIENTS
from drrl.settings.presets import default_kind

NOT_FLAGS = {"env"}  # the command's argument (and --env)


def flag_of(setting: FlatSetting) -> str | None:
    """The option that sets ``setting``, or None: a model-based table's setting has one only where its field names
    it (``json_schema_extra["flag"]``); a table of its own (env_schedule) is set in a file or by --set."""
    extra = setting.field.json_schema_extra if isinstance(setting.field.json_schema_extra, dict) else {}
    if setting.name.startswith(f"{TABLE}."):
        return f"--{extra['flag']}" if "flag" in extra else None
    if setting.name in NOT_FLAGS or _is_table(setting.field):
        return None
    return f"--{setting.name.replace('_', '-')}"


def _is_table(field: FieldInfo) -> bool:
    kinds = typing.get_args(field.annotation) or (field.annotation,)
    return any(isinstance(kind, type) and issubclass(kind, BaseModel) for kind in kinds)


def _param_type(setting: FlatSetting):
    field = setting.field
    extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
    choices = extra.get("choices")
    if isinstance(choices, list):
        return click.Choice([str(choice) for choice in choices])
    if setting.name == "start_from":
        return click.Path(exists=True, file_okay=False)
    kinds = {_plain(kind) for kind in typing.get_args(field.annotation) or (field.annotation,)} - {type(None)}
    if kinds == {bool}:
        return click.BOOL
    if kinds == {int}:
        return INTEGER
    if kinds == {float}:
        return float
    if typing.get_origin(field.annotation) is tuple:
        return WIDTHS
    return str


def _plain(kind):
    """A type without its pydantic validators: ``int`` for ``Annotated[int, ...]``."""
    return typing.get_args(kind)[0] if typing.get_origin(kind) is typing.Annotated else kind


class Widths(click.ParamType):
    """Layer widths, W[,W...], in ASCII digits."""

    name = "W[,W...]"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        return tuple(INTEGER.convert(width, param, ctx) for width in str(value).split(","))


WIDTHS = Widths()


def help_of(setting: FlatSetting) -> str:
    default = default_of(setting)
    shown = "" if default is None else f"  [default: {_shown(default)}]"
    return f"{setting.field.description or ''}{shown}"  # a task's preset may set it otherwise: --show-settings


def _shown(default) -> str:
    if isinstance(default, bool):
        return "on" if default else "off"
    return ",".join(map(str, default)) if isinstance(default, tuple) else str(default)


def default_of(setting: FlatSetting):
    """The schema's default of ``setting``; None where it has none (unset, required, or a part made afresh)."""
    default = setting.field.default
    return None if default is PydanticUndefined else default


FLAGS = {setting.name: flag for setting in FLAT.values() if (flag := flag_of(setting))}


def settings_options(command):
    """The settings options of ``drrl train``: every flat setting's own option, --search, --set, --show-settings."""
    options = [
        click.option(
            "--search",
            "search",
            type=click.Choice((*PARAMETER_SEARCHES, *POLICY_GRADIENTS)),
            help=f"{SEARCH_DESCRIPTION}  [default: pgpe, or the task's preset]",
        ),
        *(_option(name, flag) for name, flag in FLAGS.items()),
        click.option(
            "--model-based/--model-free",
            default=None,
            help="Model-based PGPE: fit a world model to real episodes and search in it (its settings: "
            "model_based.*; popsize and episodes-per-candidate then count imagined episodes), or PGPE on the env "
            "alone  [default: the task's (model-based for the swing-up, most Baxter reaches and the tasks seen "
            "as frames), else model-free]",
        ),
        click.option(
            "--set",
            "assignments",
            multiple=True,
            metavar="NAME=VALUE",
            help="any setting, by its name in a config file, e.g. --set model_based.disagreement_penalty=1 (the value "
            "as TOML reads it; repeat the option)",
        ),
        click.option(
            "--show-settings",
            is_flag=True,
            help="print the settings the run would use and where each came from (default, preset, file, flag), "
            "then stop",
        ),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def _key(name: str) -> str:
    """The command function's keyword for the setting ``name`` (a table's dot is not one)."""
    return name.replace(".", "__")


def _option(name: str, flag: str):
    """The option of the flat setting ``name``: an on/off setting is ``--flag/--no-flag`` (unset where neither is
    given, so that a file or preset decides), the rest take a value."""
    kind = _param_type(FLAT[name])
    if kind is click.BOOL:
        return click.option(f"{flag}/--no-{flag[2:]}", _key(name), default=None, help=help_of(FLAT[name]))
    return click.option(flag, _key(name), type=kind, help=help_of(FLAT[name]))


def given_settings(options: dict, assignments: tuple[str, ...]) -> dict:
    """The flat settings the options give (unset ones left out)."""
    settings: dict = {}
    given = [(key.replace("__", "."), value) for key, value in options.items() if value is not None]
    for name, value in [*given, *map(parse_assignment, assignments)]:
        if name.startswith(f"{TABLE}."):
            settings.setdefault(TABLE, {})[name.removeprefix(f"{TABLE}.")] = value
        else:
            settings[name] = value
    return settings


def parse_assignment(assignment: str) -> tuple[str, object]:
    """``NAME=VALUE`` as (name, value): the value as TOML reads it, else as the text it is."""
    name, equals, text = assignment.partition("=")
    name = name.strip()
    if not equals or not name:
        raise click.UsageError(f"--set {assignment!r}: give NAME=VALUE, e.g. --set model_based.ensemble_size=5")
    if name not in FLAT and name not in ("search", "env", "env_schedule"):
        raise click.UsageError(f"--set {assignment!r}: {name!r} is not a setting; `drrl train --help` lists them")
    try:
        value = tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError:
        value = text
    return name, value


def with_file(file_settings: dict, given: dict) -> dict:
    """The file's flat settings with the options' over them, a model_based table merged setting by setting."""
    return merged([("file", file_settings), ("flag", given)])[0]


def with_run_kind(file_settings: dict, given: dict, model_based: bool | None) -> dict:
    """``given`` with a model_based table where the run is model-based: asked for (--model-based), or neither asked
    against (--model-free) nor a file's table, and the task's default kind (``presets.default_kind``) unless a file
    or flag gives a setting only model-free runs have (a file written for a model-free run stays one). A world
    model's options on a model-free run are refused in one line."""
    user = with_file(file_settings, given)
    asked_against = model_based is False
    if model_based is None:
        search = user.get("search", "pgpe")
        model_free_only = any(
            FLAT[name].belongs_to("model-free", search) and not FLAT[name].belongs_to("model-based", search)
            for name in user
            if name in FLAT
        )
        model_based = isinstance(file_settings.get(TABLE), dict) or (
            search not in POLICY_GRADIENTS
            and not model_free_only
            and default_kind(user.get("env", "cartpole")) == "model-based"
        )
    options = given.get(TABLE)
    if options and not model_based:
        names = ", ".join(FLAGS.get(f"{TABLE}.{name}", f"--set {TABLE}.{name}") for name in options)
        fix = "drop --model-free" if asked_against else "add --model-based"
        raise click.UsageError(f"{names}: settings of a model-based run only; {fix}")
    if model_based:
        return {**given, TABLE: options or {}}
    return {**given, TABLE: None} if asked_against and file_settings.get(TABLE) is not None else given


def show_settings(config: TrainConfig, file: Path | None, file_settings: dict, flags: dict) -> str:
    """The settings of ``config``, each with where it came from: the schema's default, a preset, the file, a flag."""
    user = with_file(file_settings, flags)
    layers = [
        *((f"preset {name}", preset) for name, preset in layers_for(user)),
        (f"file {file}", file_settings),
        ("flag", flags),
    ]
    sources = merged(layers)[1]
    flat = flattened(config)
    table = flat.pop(TABLE, None)
    article = "an" if config.world.kind[0] in "aeiou" else "a"
    lines = [f"settings of {article} {config.world.kind} run on {config.env}:"]
    lines += [_line(name, value, sources.get(name, "default")) for name, value in flat.items()]
    if table is not None:
        lines.append(f"[{TABLE}]")
        lines += [_line(name, value, sources.get(f"{TABLE}.{name}", "default")) for name, value in table.items()]
    return "\n".join(lines)


def reference_table() -> str:
    """Every setting as a Markdown table (the settings reference page): its name in a config file, its option, its
    default and its one description."""
    rows = ["| setting | option | default | what it is |", "| --- | --- | --- | --- |"]
    for name, setting in FLAT.items():
        default = default_of(setting)
        shown = "" if default is None else _toml(default)
        flag = FLAGS.get(name, "--set" if name != "env" else "ENV, --env")
        rows.append(f"| `{name}` | `{flag}` | {f'`{shown}`' if shown else ''} | {setting.field.description or ''} |")
    return "\n".join(rows)


def _line(name: str, value, source: str) -> str:
    text = f"{name} = {_toml(value)}"
    return f"{text:48} # {source}"


def _toml(value) -> str:
    if value is None:
        return "(unset)"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(map(_toml, value)) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{key} = {_toml(item)}" for key, item in value.items()) + "}"
    return str(value)
