"""Evaluating candidates on batched environments, here (local) or on a Ray cluster."""

from drrl.rollout.backend import BACKENDS, Backend, Workload, make_backend
from drrl.rollout.evaluate import Evaluation, NonFiniteOutput, episode_seeds, evaluate
from drrl.rollout.local import LocalBackend

__all__ = ["BACKENDS", "Backend", "Evaluation", "LocalBackend", "NonFiniteOutput", "Workload", "episode_seeds",
           "evaluate", "make_backend"]
