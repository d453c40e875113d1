"""The flat form people write settings in, and the one place presets are merged into it.

In the flat form every setting has one short name (``popsize``, ``observation_norm``, ``demonstrations``), and a
model-based run's world is a ``model_based`` table; ``nested`` turns it into the parts of ``TrainConfig``. A run's
settings are layers merged in one order: the schema's defaults, the presets of its task (``presets.presets_for``),
the user's file, then the command line's flags, a later layer's setting over an earlier one's (a ``model_based``
table merged setting by setting). ``merged`` also says where each setting came from, for ``drrl train
--show-settings``.

Each flat name is a field of one part; ``FLAT`` says which. A setting of a part the run does not have (a sampler for
CMA-ES, ``observation_norm`` for a model-based run) is placed where that part would hold it, so that validation
refuses it there, and ``describe_errors`` says whose setting it is.
"""

from __future__ import annotations

from dataclasses import dataclass

from pydantic.fields import FieldInfo

from drrl.settings import presets
from drrl.settings.parts import (
    POLICY_GRADIENTS,
    ActionSpaceSettings,
    CMAESSettings,
    Demonstrations,
    Measuring,
    ModelBasedSettings,
    ModelFreeSettings,
    Part,
    PGPESettings,
    PolicyGradientSettings,
    RunSettings,
    StartFrom,
)

WORLDS: dict[str, type[Part]] = {
    "model-free": ModelFreeSettings,
    "model-based": ModelBasedSettings,
    "action-space": ActionSpaceSettings,
}
SEARCHES: dict[str, type[Part]] = {
    "pgpe": PGPESettings,
    "cmaes": CMAESSettings,
    "sep-cmaes": CMAESSettings,
    "reinforce": PolicyGradientSettings,
    "enac": PolicyGradientSettings,
}
START: dict[str, tuple[type[Part], str]] = {  # flat name -> (part, its field)
    "demonstrations": (Demonstrations, "episodes"),
    "demonstration_rounds": (Demonstrations, "rounds"),
    "demonstration_noise": (Demonstrations, "noise"),
    "start_from": (StartFrom, "run"),
}
TABLE = "model_based"  # the flat form's table of a model-based world
STRUCTURE = {"kind", "search", "start", "name"}  # fields that make the parts, not settings
RENAMED = {"generations": "generations_per_iteration"}  # in an older drrl's model_based table
RENAMED_SAMPLERS = {"reinforce": "single"}  # an older drrl's name of PGPE's single sampler


@dataclass(frozen=True)
class FlatSetting:
    """One setting of the flat form: where it goes, its field (description, default, bounds), and the parts that
    have it (names of worlds or searches)."""

    name: str
    path: tuple[str, ...]  # in TrainConfig's nested form
    field: FieldInfo
    owners: tuple[str, ...]

    def belongs_to(self, kind: str, search: str) -> bool:
        """Whether a run of world ``kind`` with ``search`` has this setting."""
        return "run" in self.owners or kind in self.owners or search in self.owners


def _table() -> dict[str, FlatSetting]:
    found: dict[str, FlatSetting] = {}

    def add(name: str, path: tuple[str, ...], field: FieldInfo, owner: str) -> None:
        if name in found:
            old = found[name]
            found[name] = FlatSetting(name, old.path, old.field, (*old.owners, owner))
        else:
            found[name] = FlatSetting(name, path, field, (owner,))

    for name, field in RunSettings.model_fields.items():
        if name not in ("measuring", "world"):
            add(name, (name,), field, "run")
    for name, field in Measuring.model_fields.items():
        add(name, ("measuring", name), field, "run")
    for search, search_part in SEARCHES.items():
        for name, field in search_part.model_fields.items():
            if name not in STRUCTURE:
                add(name, ("world", "search", name), field, search)
    for kind, world_part in WORLDS.items():
        for name, field in world_part.model_fields.items():
            if name not in STRUCTURE:
                shared = kind != "model-based" or name in ModelFreeSettings.model_fields  # reward_shift
                add(name if shared else f"{TABLE}.{name}", ("world", name), field, kind)
    for name, (start_part, field_name) in START.items():
        owners = ("model-free",) if start_part is Demonstrations else tuple(WORLDS)
        for owner in owners:
            add(name, ("world", "start", field_name), start_part.model_fields[field_name], owner)
    return found


FLAT = _table()
SEARCH_DESCRIPTION = (
    "the search: PGPE (the thesis), CMA-ES with a full or diagonal covariance, or an action-space policy gradient "
    "(REINFORCE with a baseline, eNAC)"
)


def is_flat(data) -> bool:
    """Whether ``data`` is settings in the flat form (config.json's nested form has a ``world``)."""
    return isinstance(data, dict) and "world" not in data and "measuring" not in data


def run_kind(flat: dict) -> str:
    """The world a run of these flat settings steps: model-based with a ``model_based`` table, action-space for a
    policy gradient, else model-free."""
    if flat.get(TABLE) is not None:
        return "model-based"
    return "action-space" if flat.get("search") in POLICY_GRADIENTS else "model-free"


def layers_for(flat: dict) -> list[tuple[str, dict]]:
    """The preset layers (name, flat settings) a run of ``flat`` starts from, each less the settings the run does not
    have: a preset is written for a task, and its PGPE settings do not apply to a CMA-ES search chosen on top."""
    layers = presets.presets_for(flat.get("env", "cartpole"), run_kind(flat), flat.get("search"))
    settings = merged([*layers, ("given", flat)])[0]
    own = settings_of(run_kind(settings), str(settings.get("search", _default_search(run_kind(settings)))))
    return [(name, {key: value for key, value in layer.items() if key in own}) for name, layer in layers]


def _default_search(kind: str) -> str:
    return "reinforce" if kind == "action-space" else "pgpe"


def merged(layers: list[tuple[str, dict]]) -> tuple[dict, dict[str, str]]:
    """Flat settings of ``layers`` merged in order, and where each came from."""
    settings: dict = {}
    sources: dict[str, str] = {}
    for source, layer in layers:
        for key, value in layer.items():
            if key == TABLE and isinstance(value, dict) and isinstance(settings.get(TABLE), dict):
                settings[TABLE] = {**settings[TABLE], **value}
            else:
                settings[key] = value
            if key == TABLE and isinstance(value, dict):
                sources.update({f"{TABLE}.{name}": source for name in value})
            sources[key] = source
    return settings, sources


def nested(flat: dict, legacy: bool = False) -> dict:
    """``flat`` on top of its task's presets, in the nested form of ``RunSettings``. ``legacy``: config.json of an older
    drrl, which recorded every setting of every part: those of parts the run does not have are dropped."""
    settings = _renamed(flat) if legacy else merged([*layers_for(flat), ("given", flat)])[0]
    kind = run_kind(settings)
    search = settings.get("search", _default_search(kind))
    world: dict = {"kind": kind, "search": {"name": search}}
    out: dict = {"measuring": {}, "world": world}
    start: dict = {}
    table = settings.get(TABLE)
    given = {key: value for key, value in settings.items() if key not in ("search", TABLE)}
    if isinstance(table, dict):
        given.update({f"{TABLE}.{key}": value for key, value in table.items()})
    elif table is not None:
        raise ValueError(f"{TABLE}: Input should be a valid dictionary, a table of settings (got {table!r:.60})")
    for key, value in given.items():
        setting = FLAT.get(key)
        owned = setting is not None and setting.belongs_to(kind, search)
        if key in START and owned:
            start_part, field_name = START[key]
            if value not in (None, 0) or key not in ("demonstrations", "start_from"):
                start.setdefault(start_part.__name__, {})[field_name] = value
            continue
        if not owned and (legacy or value is None):
            continue  # an older drrl's record of another part's setting; an unset setting of another part
        if setting is None:  # refused by validation as unknown, with the settings that are
            if key.startswith(f"{TABLE}."):
                world[key.removeprefix(f"{TABLE}.")] = value
            else:
                out[key] = value
            continue
        if key in START:
            world[key] = value  # refused: another world's start
            continue
        path = setting.path
        target = out
        for part in path[:-1]:
            target = target.setdefault(part, {})
        target[path[-1]] = value
    if Demonstrations.__name__ in start and "episodes" not in start[Demonstrations.__name__]:
        if not legacy:  # an older drrl recorded rounds and noise of no demonstrations
            given_names = ", ".join(name for name in START if name in given and START[name][0] is Demonstrations)
            raise ValueError(
                f"{given_names}: settings of a run that starts from demonstrations; give demonstrations (≥ 1) too"
            )
        del start[Demonstrations.__name__]
    if len(start) > 1 and not legacy:  # a start given wins over a preset's other one; two given are refused
        given_starts = [
            part for part in (Demonstrations, StartFrom) if any(START[k][0] is part for k in flat if k in START)
        ]
        if len(given_starts) > 1:
            raise ValueError("demonstrations and start_from: a run starts from one of them, not both")
        start = {given_starts[0].__name__: start[given_starts[0].__name__]} if given_starts else start
    if len(start) > 1:
        world["start"] = {**start[Demonstrations.__name__], **start[StartFrom.__name__]}  # refused: two starts
    elif start:
        world["start"] = next(iter(start.values()))
    return out


def _renamed(flat: dict) -> dict:
    """An older drrl's flat settings with the names of today."""
    renamed = dict(flat)
    if isinstance(renamed.get(TABLE), dict):
        renamed[TABLE] = {RENAMED.get(key, key): value for key, value in renamed[TABLE].items()}
    if isinstance(renamed.get("sampler"), str):
        renamed["sampler"] = RENAMED_SAMPLERS.get(renamed["sampler"], renamed["sampler"])
    return renamed


def flat_name(location: tuple) -> str:
    """The flat name of a setting at ``location`` in the nested form (as validation errors give it)."""
    tags = {*WORLDS, *SEARCHES, Demonstrations.__name__, StartFrom.__name__}
    parts = [str(part) for index, part in enumerate(location) if not (index and str(part) in tags)]
    model_based = "model-based" in map(str, location)
    for setting in FLAT.values():
        table = setting.name.startswith(f"{TABLE}.")
        if tuple(parts) == setting.path and (table == model_based or not table):
            return setting.name
    plain = parts[-1] in FLAT or parts[-1] in ModelFreeSettings.model_fields
    if model_based and len(parts) == 2 and parts[0] == "world" and not plain:
        return f"{TABLE}.{parts[1]}"
    if parts[:2] == ["world", "start"] and len(parts) == 3:
        return {field: name for name, (_, field) in START.items()}.get(parts[2], parts[2])
    return parts[-1] if parts[:1] == ["world"] else ".".join(parts)


def owners_of(name: str) -> tuple[str, ...]:
    """The worlds or searches that have the setting ``name`` (flat), e.g. ("pgpe",) for sampler."""
    bare = name.removeprefix(f"{TABLE}.")
    setting = FLAT.get(name) or FLAT.get(f"{TABLE}.{bare}")
    return () if setting is None else setting.owners


def settings_of(kind: str, search: str) -> set[str]:
    """The flat names a run of world ``kind`` and ``search`` has (its model_based table's prefixed)."""
    own = {name for name, setting in FLAT.items() if setting.belongs_to(kind, search)}
    return own | {"search", *([TABLE] if kind == "model-based" else [])}


def flattened(config: RunSettings) -> dict:
    """``config`` in the flat form (every setting of its parts), the form ``nested`` reads back."""
    dumped = config.model_dump(mode="json")
    flat: dict = {"search": config.search.name}
    kind, search = config.world.kind, config.search.name
    for name, setting in FLAT.items():
        if not setting.belongs_to(kind, search):
            continue
        if name in START:
            start = config.world.start
            start_part, field_name = START[name]
            if isinstance(start, start_part):
                flat[name] = getattr(start, field_name)
            continue
        value = dumped
        for part in setting.path:
            value = value[part]
        if name.startswith(f"{TABLE}."):
            flat.setdefault(TABLE, {})[name.removeprefix(f"{TABLE}.")] = value
        else:
            flat[name] = value
    return flat
