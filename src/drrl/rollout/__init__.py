"""Evaluating candidates on batched environments."""

from drrl.rollout.evaluate import Evaluation, evaluate, episode_seeds

__all__ = ["Evaluation", "episode_seeds", "evaluate"]
