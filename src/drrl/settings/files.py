"""Settings files (TOML or JSON, in the flat form) and the one-line errors of settings that do not validate."""

from __future__ import annotations

import difflib
import json
import os
import stat
import tomllib
from pathlib import Path

from pydantic import ValidationError

from drrl.settings.flat import FLAT, SEARCHES, TABLE, WORLDS, flat_name, owners_of

MAX_CONFIG_BYTES = 1024 * 1024


def load_config_file(path: Path) -> dict:
    """Read a TOML or JSON config file (JSON by a ``.json`` suffix in any case) into a plain dict, validated later
    with the command-line overrides. Only a regular file is read, and at most ``MAX_CONFIG_BYTES`` of it: a FIFO or
    a device (/dev/zero) would block or never end."""
    kind = "JSON" if path.suffix.lower() == ".json" else "TOML"
    text = read_text(path, f"config file {path}", MAX_CONFIG_BYTES, kind)
    try:
        settings = json.loads(text, object_pairs_hook=_once_each) if kind == "JSON" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as error:
        raise ValueError(f"config file {path} is not valid {kind}: {error}") from None
    except RecursionError:
        raise ValueError(f"config file {path} nests its tables too deeply to be a drrl config") from None
    except RepeatedKey as error:
        raise ValueError(f"config file {path} is not a drrl config: {error}") from None
    except ValueError:  # a number of over 4,300 digits (Python's limit on reading one)
        raise ValueError(
            f"config file {path} is not a drrl config: it holds a number too long to be a setting"
        ) from None
    if not isinstance(settings, dict):
        raise ValueError(
            f"config file {path} must hold an object of settings (name: value), not a {type(settings).__name__}"
        )
    return settings


def read_text(path: Path, what: str, limit: int, kind: str = "text") -> str:
    """A regular file's UTF-8 text (a byte-order mark allowed) of at most ``limit`` bytes; ValueError naming
    ``what`` for anything else: a missing file, a folder, a FIFO or device, a larger file, bytes that are not UTF-8."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise ValueError(f"{what} is not a regular file (a folder, FIFO or device); give a {kind} file")
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as error:
        raise ValueError(f"cannot read {what}: {error.strerror}") from None
    if len(data) > limit:
        raise ValueError(f"{what} is over {limit // 1024} KiB; a config holds a few settings")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ValueError(f"{what} is not {kind} text: byte {error.start} is not UTF-8") from None


class RepeatedKey(ValueError):
    """A JSON object gives one key twice."""


def _once_each(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object whose keys are all different (json.loads would keep the last of a key given twice)."""
    settings: dict = {}
    for key, value in pairs:
        if key in settings:
            raise RepeatedKey(f"{key!r} is given twice")
        settings[key] = value
    return settings


def describe_errors(error: ValidationError) -> str:
    """One line per invalid setting, by its flat name: what it is, the value given and what is allowed."""
    lines = []
    errors = error.errors()
    places = [tuple(item["loc"]) for item in errors]
    for item in errors:
        location = tuple(item["loc"])
        if any(len(other) > len(location) and other[: len(location)] == location for other in places):
            continue  # a setting's own error follows from an error in one of its items, shown instead
        index = next((part for part in location if isinstance(part, int)), None)
        location = tuple(part for part in location if not isinstance(part, int))
        name = flat_name(location) if location else ""
        message = item["msg"].removeprefix("Value error, ")
        if index is not None:
            message = f"item {index + 1}: {message}"
        if item["type"] == "extra_forbidden":
            message = _not_here(name, location)
        elif item["type"] == "union_tag_invalid":
            message = f"{item['ctx']['tag']!r} is not one of: {item['ctx']['expected_tags']}"
        setting = FLAT.get(name) or FLAT.get(f"{TABLE}.{name}")
        about = f" — {name}: {setting.field.description}" if setting and setting.field.description else ""
        shown = location and item["type"] != "extra_forbidden" and not isinstance(item["input"], dict)
        given = f" (got {short_repr(item['input'])})" if shown else ""
        lines.append(f"{name}: {message}{given}{about if shown else ''}" if name else message)
    return "\n".join(lines)


def _not_here(name: str, location: tuple) -> str:
    """Why a setting is refused where it was given: whose setting it is, or that there is no such setting."""
    owners = owners_of(name)
    tags = [str(part) for part in location]
    searches = [owner for owner in owners if owner in SEARCHES]
    if searches:
        here = next((tag for tag in tags if tag in SEARCHES), "this run's")
        return f"a setting of the {' and '.join(searches)} search, not of {here}"
    if owners:
        here = next((tag for tag in tags if tag in WORLDS), "this")
        return f"a setting of {' and '.join(owners)} runs, not of {here} ones"
    table = name.startswith(f"{TABLE}.")
    names = [key for key in FLAT if key.startswith(f"{TABLE}.") == table]
    names = [key.removeprefix(f"{TABLE}.") for key in names] if table else ["env", "policy", "search", *names[2:]]
    close = difflib.get_close_matches(name.removeprefix(f"{TABLE}."), names, n=1)
    known = ", ".join(names)
    return f"not a setting{f' (did you mean {close[0]}?)' if close else ''}; the settings are: {known}"


def short_repr(value, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters for a one-line message."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
