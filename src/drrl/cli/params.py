"""Command-line parameter types of the ``drrl`` command."""

from __future__ import annotations

import click

from drrl.settings import short_repr

MAX_DIGITS = 20  # a whole number of more digits is a typo, and Python refuses to read one of over 4,300


class AsciiInt(click.ParamType):
    """A whole number written in ASCII digits (Python's int() would also read "٨" or "1_000"), within ``low`` to
    ``high`` where given; a bad one is refused saying what is allowed."""

    name = "integer"

    def __init__(self, low: int | None = None, high: int | None = None):
        self.low, self.high = low, high

    def convert(self, value, param, ctx):
        if isinstance(value, int) and not isinstance(value, bool):
            return self._within(value, param, ctx)
        text = str(value).strip()
        digits = text.removeprefix("-").removeprefix("+")
        if not (digits.isascii() and digits.isdigit()):
            self.fail(f"{short_repr(str(value), 40)} is not {self._allowed()}", param, ctx)
        if len(digits) > MAX_DIGITS:
            self.fail(
                f"{short_repr(str(value), 40)} has {len(digits)} digits; {self._allowed()} has at most {MAX_DIGITS}",
                param,
                ctx,
            )
        return self._within(int(text), param, ctx)

    def _within(self, number: int, param, ctx) -> int:
        if (self.low is not None and number < self.low) or (self.high is not None and number > self.high):
            self.fail(f"{number} is not {self._allowed()}", param, ctx)
        return number

    def _allowed(self) -> str:
        if self.low is not None and self.high is not None:
            return f"a whole number from {self.low} to {self.high}"
        if self.low is not None:
            return f"a whole number ≥ {self.low}"
        return "a whole number in the digits 0-9"


INTEGER = AsciiInt()
COUNT = AsciiInt(low=1)
SEED = AsciiInt(low=0, high=2**32 - 1)  # what NumPy's and torch's generators take
EPISODES = AsciiInt(low=1, high=10_000)  # measured at once: more would not fit in memory for a large observation
