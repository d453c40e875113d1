"""Compact policy specs for the command line: ``linear``, ``linear:nobias``, ``multilinear:8``, ``mlp:32,32``,
``rnn:16``, ``lstm:32,32``."""

from __future__ import annotations

from drrl.policies.base import Policy
from drrl.policies.feedforward import linear, mlp, multilinear
from drrl.policies.recurrent import lstm, rnn

ACCEPTED_FORMS = ("linear, linear:nobias, multilinear:W[,W...], mlp:W[,W...], rnn:W[,W...], lstm:W[,W...] "
                  "(W = a positive layer width)")
POLICY_KINDS = ("linear", "multilinear", "mlp", "rnn", "lstm")
LAYERED = {"multilinear": multilinear, "mlp": mlp, "rnn": rnn, "lstm": lstm}  # kinds that take layer widths


def make_policy(spec: str, observation_size: int, action_size: int) -> Policy:
    """Build the policy that ``spec`` names, for the given observation and action sizes."""
    kind, _, arguments = spec.strip().partition(":")
    if kind == "linear":
        if arguments not in ("", "nobias"):
            raise _malformed(spec)
        return linear(observation_size, action_size, bias=arguments != "nobias")
    if kind in LAYERED:
        return LAYERED[kind](observation_size, action_size, _widths(spec, arguments))
    raise ValueError(f"unknown policy kind {kind!r} in {spec!r}; accepted forms: {ACCEPTED_FORMS}")


def _widths(spec: str, arguments: str) -> list[int]:
    try:
        widths = [int(width) for width in arguments.split(",")]
    except ValueError:
        raise _malformed(spec) from None
    if not widths or min(widths) < 1:
        raise _malformed(spec)
    return widths


def _malformed(spec: str) -> ValueError:
    return ValueError(f"malformed policy spec {spec!r}; accepted forms: {ACCEPTED_FORMS}")
