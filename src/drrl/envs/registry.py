"""Everything drrl knows about an environment, in one entry per environment.

An entry holds the Gymnasium id and drrl's short alias, the task's verdict (what "solved" means) and how
``drrl eval`` explains it, the task's reward and end in closed form of the observation when there is one, and of the
action where the task charges it (imagined episodes then use them instead of a learned reward), the observation
entries that follow in closed form from the others (imagined observations are completed by them), the reward of a
step that ends the episode where the step alone decides it (imagined episodes with a learned end then pay it), the
task's reflection symmetry where it has one (world models can then learn from every episode's mirror image too), a
scripted demonstrator where the task has one (a run's first centre can be cloned from its episodes). The settings
that suit a task are presets (``drrl.settings.presets``), not part of its entry. Each environment registers its
entry from its own module (``register``), which also registers it with Gymnasium; a family of ids made from others,
such as ``Pixels/ID`` for any ``ID``, registers each member when it is first named (``register_family``).
An environment that drrl does not know is any registered Gymnasium id; its entry has the verdict "solved" where
Gymnasium gives the task a ``reward_threshold`` or the field a usual level (a mean return at or above it)
(``drrl.envs.gymnasium_tasks``).
"""

from __future__ import annotations

import difflib
import importlib
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace

import gymnasium
import numpy as np
import torch

from drrl.envs.gymnasium_tasks import ACTION_COSTS, COMPLETIONS, DRRL_LEVELS, MIRRORS, REWARDS

# (episode_returns (P, E), terminated (P, E)) -> {criterion: met}
Verdict = Callable[[torch.Tensor, torch.Tensor], dict[str, bool]]
# (episode_returns (1, E), terminated (1, E)) -> one line explaining the verdict
Explanation = Callable[[torch.Tensor, torch.Tensor], str]
# (next observations (N, o), 1-based steps (N,)) -> (rewards (N,), terminated (N,))
RewardFunction = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
# actions (N, a), as the env receives them -> the reward's share that depends on them, as a cost (N,)
ActionCost = Callable[[np.ndarray], np.ndarray]
# 1-based steps (N,) at which episodes end by termination -> the rewards of those steps (N,)
EndReward = Callable[[np.ndarray], np.ndarray]
# observations (N, o) -> the env's actions (N, a): a scripted policy without memory (drrl.training.cloning copies
# its episodes)
Demonstrator = Callable[[np.ndarray], np.ndarray]
# (observations (N, o), predicted next observations (N, o)) -> the next ones with the entries that follow from the
# rest recomputed
ObservationFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]
# (observations (N, o), actions (M, a)) -> their mirror images under the task's reflection symmetry, which leaves
# rewards and ends as they are
Mirror = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class EnvEntry:
    """What drrl knows of one environment; only ``env_id`` is needed."""

    env_id: str
    alias: str | None = None
    verdict: Verdict | None = None
    explain: Explanation | None = None
    reward: RewardFunction | None = None
    action_cost: ActionCost | None = None  # taken from ``reward`` where the task charges its actions
    complete_observation: ObservationFunction | None = None  # e.g. Baxter's end-point offsets from its joint angles
    end_reward: EndReward | None = None  # a terminating step's reward where only the step decides it (5.8's failure)
    mirror: Mirror | None = None  # the task's reflection symmetry, e.g. the cart-poles' left-right flip
    demonstrator: Demonstrator | None = None  # a scripted policy a run's first centre can be cloned from

    def criteria(self) -> tuple[str, ...]:
        """The names of the verdict's criteria (metrics.csv columns); none without a verdict."""
        if self.verdict is None:
            return ()
        return tuple(self.verdict(torch.zeros(1, 1), torch.zeros(1, 1, dtype=torch.bool)))

    def judge(self, episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
        return {} if self.verdict is None else self.verdict(episode_returns, terminated)


ENTRIES: dict[str, EnvEntry] = {}  # by Gymnasium id
FAMILIES: dict[str, Callable[[str], None]] = {}  # id prefix -> registers a member id of the family when first named


def register(
    entry: EnvEntry,
    entry_point: str,
    vector_entry_point: str | None = None,
    kwargs: dict | None = None,
    max_episode_steps: int | None = None,
) -> None:
    """Register ``entry`` with drrl and its environment with Gymnasium."""
    gymnasium.register(
        id=entry.env_id,
        entry_point=entry_point,
        vector_entry_point=vector_entry_point,
        kwargs=dict(kwargs or {}),
        max_episode_steps=max_episode_steps,
    )
    ENTRIES[entry.env_id] = entry


def register_family(prefix: str, register_member: Callable[[str], None]) -> None:
    """A family of ids made on demand, such as ``Pixels/ID`` for any ``ID`` (``drrl.envs.rendered``):
    ``register_member(env_id)`` registers one (``register``) or raises a ValueError saying why it cannot be."""
    FAMILIES[prefix] = register_member


def _member(env_id: str) -> EnvEntry | None:
    """The entry of a family's member, registered in this process when first named; None for any other id."""
    for prefix, register_member in FAMILIES.items():
        if env_id.startswith(prefix):
            inner = env_id.removeprefix(prefix)
            nested = next((other for other in FAMILIES if inner.startswith(other)), None)
            if nested is not None:
                raise ValueError(
                    f"{env_id[:60]!r}{'...' if len(env_id) > 60 else ''}: {prefix}ID takes a plain env id, not one of "
                    f"{nested}ID (e.g. {prefix}CartPole-v1)"
                )
            if env_id not in ENTRIES:
                register_member(env_id)
            return ENTRIES[env_id]
    return None


def aliases() -> dict[str, str]:
    """alias -> Gymnasium id, for drrl's own environments."""
    return {entry.alias: env_id for env_id, entry in ENTRIES.items() if entry.alias}


def is_own(name: str) -> bool:
    """Whether ``name`` (an alias or a Gymnasium id) is one of drrl's own environments."""
    return own_entry(name) is not None


def own_entry(name: str) -> EnvEntry | None:
    """The entry of one of drrl's own environments (an alias or a Gymnasium id); None for any other name."""
    env_id = aliases().get(name, name)
    try:
        _member(env_id)
    except ValueError:  # ``lookup`` says why
        return None
    return ENTRIES.get(env_id)


def _can_make(name: str) -> bool:
    """Whether the module behind a registered id imports here (its dependencies are installed)."""
    entry_point = gymnasium.spec(aliases().get(name, name)).entry_point
    if not isinstance(entry_point, str):
        return True
    try:
        importlib.import_module(entry_point.partition(":")[0])
    except (ImportError, gymnasium.error.DependencyNotInstalled):
        return False
    return True


def lookup(name: str) -> EnvEntry:
    """The entry for ``name``: an alias such as ``cartpole``, a member of a family such as ``Pixels/Pendulum-v1``,
    any registered Gymnasium id, or Gymnasium's ``module:ID``, an id that importing ``module`` registers (a user's
    own env: run folders record the name, so eval, render and resume import the module again)."""
    module, colon, rest = name.partition(":")
    if colon:
        import_registering(module, name)
        name = rest
    env_id = aliases().get(name, name)
    member = _member(env_id)
    if member is not None:
        return member
    if env_id not in gymnasium.registry:
        if not name.strip():
            raise ValueError(f"the environment name is empty; drrl's own: {_listed(aliases())}")
        close = [
            match
            for match in difflib.get_close_matches(name[:200], [*aliases(), *gymnasium.registry], n=5, cutoff=0.8)
            if _can_make(match)
        ][:3]
        hint = f"did you mean {' or '.join(close)}? " if close else ""
        shown = repr(name) if len(name) <= 60 else repr(name[:57]) + "..."
        raise ValueError(
            f"unknown environment {shown}; {hint}drrl's own: {_listed(aliases())}; or any id "
            f"registered with Gymnasium (e.g. Pendulum-v1; gymnasium.pprint_registry() lists them), or "
            f"{', or '.join(prefix + 'ID' for prefix in FAMILIES)} to see one of them through its camera"
        )
    return ENTRIES.get(env_id) or gymnasium_entry(env_id)


def import_registering(module: str, name: str) -> None:
    """Import ``module``, which registers envs with Gymnasium, from the Python path or the working folder (as
    ``python -m`` would see it); whatever stops the import is one ValueError naming the module."""
    if not module.replace(".", "").replace("_", "").isalnum():
        raise ValueError(f"{name[:80]!r}: {module[:40]!r} is not a Python module name (MODULE:ID, e.g. my_envs:Arm-v0)")
    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    try:
        importlib.import_module(module)
    except Exception as error:  # the user's module: any error in it is theirs to see, in one line
        raise ValueError(
            f"cannot import {module!r} for the env {name[:80]!r}: {type(error).__name__}: {error}"
        ) from None


def _listed(names) -> str:
    """Names for one line: a family of more than three sharing their first two words as one "family*" (`drrl train
    --help` lists every alias)."""
    families: dict[str, list[str]] = {}
    for name in names:
        families.setdefault("-".join(name.split("-")[:2]), []).append(name)
    shown = [
        f"{family}* ({len(members)} envs)" if len(members) > 3 else ", ".join(members)
        for family, members in families.items()
    ]
    return ", ".join(shown) + " (`drrl train --help` lists them all)"


def gymnasium_entry(env_id: str) -> EnvEntry:
    """The entry of a Gymnasium env drrl has no module for: solved at its spec's ``reward_threshold`` or drrl's own
    level (``DRRL_LEVELS``, where the spec has none or one out of reach), if there is one, with its reward in closed
    form where drrl knows it."""
    spec = gymnasium.spec(env_id)
    threshold, source = DRRL_LEVELS.get(env_id, (spec.reward_threshold, None))
    entry = EnvEntry(
        env_id,
        reward=REWARDS.get(env_id),
        action_cost=ACTION_COSTS.get(env_id),
        complete_observation=COMPLETIONS.get(env_id),
        mirror=MIRRORS.get(env_id),
    )
    if threshold is None:
        return entry

    def verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
        return {"solved": bool(episode_returns.mean() >= threshold)}

    def explain(episode_returns: torch.Tensor, terminated: torch.Tensor) -> str:
        whose = "Gymnasium's reward_threshold" if source is None else f"drrl's level: {source}"
        return f"({env_id} counts as solved at a mean return ≥ {threshold:g}, {whose})"

    return replace(entry, verdict=verdict, explain=explain)
