"""Command-line parameter types of the ``drrl`` command."""

from __future__ import annotations

import click


class AsciiInt(click.ParamType):
    """A whole number written in ASCII digits (Python's int() would also read "٨" or "1_000")."""

    name = "integer"

    def convert(self, value, param, ctx):
        text = str(value).strip()
        if not (text.lstrip("+-").isascii() and text.lstrip("+-").isdigit()):
            self.fail(f"{value!r} is not a whole number in the digits 0-9", param, ctx)
        return int(text)


INTEGER = AsciiInt()
