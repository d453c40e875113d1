"""Settings files (TOML or JSON, in the flat form) and the one-line errors of settings that do not validate."""

from __future__ import annotations

import difflib
import json
import tomllib
from pathlib import Path

from pydantic import ValidationError

from drrl.settings.flat import FLAT, SEARCHES, TABLE, WORLDS, flat_name, owners_of

MAX_CONFIG_BYTES = 1024 * 1024


def load_config_file(path: Path) -> dict:
    """Read a TOML or JSON config file into a plain dict (validated later, with command-line overrides)."""
    kind = "JSON" if path.suffix == ".json" else "TOML"
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ValueError(
                f"config file {path} is over {MAX_CONFIG_BYTES // 1024} KiB; a config holds a few settings"
            )
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark is allowed
    except OSError as error:
        raise ValueError(f"cannot read config file {path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"config file {path} is not {kind} text: byte {error.start} is not UTF-8") from None
    try:
        settings = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as error:
        raise ValueError(f"config file {path} is not valid {kind}: {error}") from None
    except RecursionError:
        raise ValueError(f"config file {path} nests its tables too deeply to be a drrl config") from None
    if not isinstance(settings, dict):
        raise ValueError(
            f"config file {path} must hold an object of settings (name: value), not a {type(settings).__name__}"
        )
    return settings


def describe_errors(error: ValidationError) -> str:
    """One line per invalid setting, by its flat name: what it is, the value given and what is allowed."""
    lines = []
    for item in error.errors():
        location = tuple(item["loc"])
        name = flat_name(location) if location else ""
        message = item["msg"].removeprefix("Value error, ")
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
