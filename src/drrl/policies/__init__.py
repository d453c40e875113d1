"""Population-batched policies whose weights PGPE searches."""

from drrl.policies.base import Policy
from drrl.policies.feedforward import FeedForward, linear, mlp, multilinear
from drrl.policies.spec import ACCEPTED_FORMS, POLICY_KINDS, make_policy

__all__ = ["ACCEPTED_FORMS", "POLICY_KINDS", "FeedForward", "Policy", "linear", "make_policy", "mlp", "multilinear"]
