"""Compact policy specs for the command line: ``linear``, ``linear:nobias``, ``multilinear:8``, ``mlp:32,32``,
``rnn:16``, ``lstm:32,32``."""

from __future__ import annotations

from drrl.policies.base import Policy
from drrl.policies.feedforward import linear, mlp, multilinear
from drrl.policies.recurrent import lstm, rnn

MAX_WIDTH = 65_536
ACCEPTED_FORMS = (
    "linear, linear:nobias, multilinear:W[,W...], mlp:W[,W...], rnn:W[,W...], lstm:W[,W...] "
    f"(W = a layer width from 1 to {MAX_WIDTH})"
)
POLICY_KINDS = ("linear", "multilinear", "mlp", "rnn", "lstm")
LAYERED = {"multilinear": multilinear, "mlp": mlp, "rnn": rnn, "lstm": lstm}  # kinds that take layer widths


def make_policy(spec: str, observation_size: int, action_size: int) -> Policy:
    """Build the policy that ``spec`` names, for the given observation and action sizes."""
    kind, widths = parse_spec(spec)
    if kind == "linear":
        return linear(observation_size, action_size, bias=widths != ["nobias"])
    return LAYERED[kind](observation_size, action_size, widths)


def parse_spec(spec: str) -> tuple[str, list]:
    """A spec's kind and its layer widths (``linear``'s: [] or ["nobias"]); ValueError with the accepted forms for
    anything else. What a run's settings check, before anything is built."""
    kind, _, arguments = spec.strip().partition(":")
    if kind == "linear":
        if arguments not in ("", "nobias"):
            raise _malformed(spec)
        return kind, [arguments] if arguments else []
    if kind in LAYERED:
        return kind, _widths(spec, arguments)
    raise ValueError(f"unknown policy kind {kind[:40]!r}; accepted forms: {ACCEPTED_FORMS}")


def _widths(spec: str, arguments: str) -> list[int]:
    words = [word.strip() for word in arguments.split(",")]
    if not all(word.isascii() and word.isdigit() for word in words):  # int() would read "٣" or "1_0" too
        raise _malformed(spec)
    widths = [int(word) for word in words]
    if min(widths) < 1 or max(widths) > MAX_WIDTH:
        raise _malformed(spec)
    return widths


def _malformed(spec: str) -> ValueError:
    shown = repr(spec) if len(spec) <= 60 else repr(spec[:57]) + "..."
    return ValueError(f"malformed policy spec {shown}; accepted forms: {ACCEPTED_FORMS}")
