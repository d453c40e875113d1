"""Search over policy parameters behind one interface (``Search``): PGPE (thesis 2.4) with
its fitness shaping and step rules for μ, and CMA-ES (full and separable) as the reference searcher."""

import torch

from drrl.search.base import Search
from drrl.search.optimizers import OPTIMIZERS, ClipUp, make_optimizer
from drrl.search.pgpe import PGPE, SAMPLERS, mirror_about_median
from drrl.search.shaping import FITNESS_SHAPINGS, centered_ranks, shape_fitness

SEARCHES = ("pgpe", "cmaes", "sep-cmaes")


def make_search(
    name: str, center: torch.Tensor, *, popsize: int, sigma_init: float, seed: int, **pgpe_settings
) -> Search:
    """The search ``name`` from ``center``; ``pgpe_settings`` (sampler, optimizer, ...) apply to PGPE only."""
    if name == "pgpe":
        return PGPE(center, popsize=popsize, sigma_init=sigma_init, seed=seed, **pgpe_settings)
    if name in ("cmaes", "sep-cmaes"):
        from drrl.search.cmaes import CMAES  # imports the cmaes package only when asked for

        return CMAES(center, popsize=popsize, sigma_init=sigma_init, separable=name == "sep-cmaes", seed=seed)
    raise ValueError(f"unknown search {name!r}; choose one of: {', '.join(SEARCHES)}")


__all__ = [
    "FITNESS_SHAPINGS",
    "OPTIMIZERS",
    "PGPE",
    "SAMPLERS",
    "SEARCHES",
    "ClipUp",
    "Search",
    "centered_ranks",
    "make_optimizer",
    "make_search",
    "mirror_about_median",
    "shape_fitness",
]
