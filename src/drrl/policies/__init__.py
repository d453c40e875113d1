"""Population-batched policies whose weights PGPE searches."""

from drrl.policies.base import Policy
from drrl.policies.feedforward import FeedForward, linear, mlp, multilinear
from drrl.policies.recurrent import LSTM, ElmanRNN, Recurrent, lstm, rnn
from drrl.policies.spec import ACCEPTED_FORMS, POLICY_KINDS, make_policy, parse_spec

__all__ = [
    "ACCEPTED_FORMS",
    "LSTM",
    "POLICY_KINDS",
    "ElmanRNN",
    "FeedForward",
    "Policy",
    "Recurrent",
    "linear",
    "lstm",
    "make_policy",
    "mlp",
    "multilinear",
    "parse_spec",
    "rnn",
]
