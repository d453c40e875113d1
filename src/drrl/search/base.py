"""The search interface: ask for candidate parameter vectors, tell their fitness (higher is better).

A search never sees an environment; where the fitness comes from is the training loop's business, so the same
search runs on real returns (model-free) and on imagined ones (model-based). ``Search`` does once what every
search shares: checking the told fitness, counting generations, the generation's metrics, and the bookkeeping
part of its state (kind, sizes, generation). A search writes only its own ``ask``, ``_update``, ``center``,
``spread``, ``_state`` and ``_load_state``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch


class Search(ABC):
    """Ask/tell over flat parameter vectors of length ``num_params``, ``popsize`` candidates a generation."""

    kind: str  # the search's name in configs and checkpoints, e.g. "pgpe"

    def __init__(self, num_params: int, popsize: int):
        self.num_params = int(num_params)
        self.popsize = int(popsize)
        self.generation = 0

    @abstractmethod
    def ask(self) -> torch.Tensor:
        """``popsize`` candidates, shape (popsize, num_params); the next tell refers to the latest ask."""

    @property
    @abstractmethod
    def center(self) -> torch.Tensor:
        """The search's current best guess (its distribution's mean), shape (num_params,): a copy."""

    @property
    @abstractmethod
    def spread(self) -> torch.Tensor:
        """The standard deviation of the search distribution per parameter, shape (num_params,): a copy."""

    @abstractmethod
    def _update(self, fitness: torch.Tensor) -> dict[str, float]:
        """Move the distribution with the checked fitness (popsize,) float32; the search's own metrics."""

    @abstractmethod
    def _state(self) -> dict:
        """The search's own changing state, as tensors and plain values."""

    @abstractmethod
    def _load_state(self, state: dict) -> None:
        """Restore ``_state``."""

    def tell(self, fitness: torch.Tensor) -> dict[str, float]:
        """Update the search from the fitness (popsize,) of the last ask's candidates, higher is better.

        Returns the generation's metrics as floats: "mean", "best", "worst" (raw fitness), "sigma_norm" (the norm
        of ``spread`` after the update) and the search's own.
        """
        fitness = self._check_fitness(fitness)
        metrics = self._update(fitness)
        self.generation += 1
        return {
            "mean": float(fitness.mean()),
            "best": float(fitness.max()),
            "worst": float(fitness.min()),
            "sigma_norm": float(self.spread.norm()),
            **metrics,
        }

    def state_dict(self) -> dict:
        """Everything that changes during a run, as tensors and plain Python values (never pickled). Restored into
        a search built with the same settings, it continues bit-identically, also between an ask and its tell."""
        return {
            "kind": self.kind,
            "num_params": self.num_params,
            "popsize": self.popsize,
            "generation": self.generation,
            **self._state(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict``; the search must have been built with the same settings."""
        for key in ("kind", "num_params", "popsize", "generation"):
            if key not in state:
                raise ValueError(f"not a {self.kind} state: it lacks {key}")
        for key in ("kind", "num_params", "popsize"):
            if state[key] != getattr(self, key):
                raise ValueError(
                    f"state is for {key}={state[key]!r} but this search has "
                    f"{key}={getattr(self, key)!r}; build it with the settings the state was saved with"
                )
        self._load_state(state)
        self.generation = int(state["generation"])

    def _check_fitness(self, fitness) -> torch.Tensor:
        fitness = torch.as_tensor(fitness).detach()
        if fitness.shape != (self.popsize,):
            raise ValueError(
                f"fitness must have shape ({self.popsize},), one value per asked candidate; "
                f"got shape {tuple(fitness.shape)}"
            )
        fitness = fitness.to(dtype=torch.float32)
        bad = torch.nonzero(~torch.isfinite(fitness)).flatten().tolist()
        if bad:
            shown = ", ".join(map(str, bad[:10])) + (", ..." if len(bad) > 10 else "")
            raise ValueError(
                f"fitness must be finite (after conversion to float32); candidate index(es) {shown} "
                f"are NaN or infinite; the search was not updated"
            )
        return fitness
