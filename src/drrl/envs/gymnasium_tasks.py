"""What drrl knows of some of Gymnasium's own tasks beyond their specs: the return usually counted as solved where
Gymnasium gives none, and settings measured to reach it where drrl's defaults for Gymnasium's envs do not
(BENCHMARKS.md, "Gymnasium's envs with drrl's defaults")."""

from __future__ import annotations

SOLVED_LEVELS = {"Pendulum-v1": -200.0}  # Pendulum-v1's spec has no reward_threshold

SUGGESTED = {
    # −145.4 over 50 fresh episodes after 51,200 episodes (33 s with EnvPool); PGPE with the same policy stayed
    # below −800: its one episode a candidate from random starts is too noisy to rank swing-up policies.
    "Pendulum-v1": {
        "search": "cmaes",
        "policy": "mlp:16",
        "popsize": 64,
        "episodes_per_candidate": 8,
        "sigma_init": 0.5,
        "budget": 51200,
    },
}
