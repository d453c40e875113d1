"""Search over policy parameters: PGPE (thesis 2.4) with its fitness shaping and step rules for μ."""

from drrl.search.optimizers import OPTIMIZERS, ClipUp, make_optimizer
from drrl.search.pgpe import PGPE, SAMPLERS, mirror_about_median
from drrl.search.shaping import FITNESS_SHAPINGS, centered_ranks, shape_fitness

__all__ = ["FITNESS_SHAPINGS", "OPTIMIZERS", "PGPE", "SAMPLERS", "ClipUp", "centered_ranks", "make_optimizer",
           "mirror_about_median", "shape_fitness"]
