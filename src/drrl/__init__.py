"""drrl: sample-efficient robot reinforcement learning after Gao (2015).

Importing drrl registers its environments with Gymnasium (``drrl/CartPole-v0``).
"""

from drrl import envs as _envs  # noqa: F401  (registers the environments)

__version__ = "0.1.0"
