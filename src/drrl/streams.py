"""Every random stream of drrl, named in one place, and the one way a seed is derived from the run seed.

A seed depends only on the run seed, the step (generation, iteration or attempt) and the stream, so that a resumed
run draws exactly what an uninterrupted one does, and no two uses of randomness in a run draw alike. A new use of
randomness takes a new stream here, with a new number.

Two pairs of streams share their number, from before the streams were named in one place (their seeds are kept, so
that every run gives the numbers it gave): a model-based run's ``IMAGINING`` and ``FITTING`` reuse the numbers of
``DEMONSTRATING`` and ``RESTARTING``, which only model-free runs use (a model-based world has neither
demonstrations nor ``restart_every``). Python's ``Enum`` makes each pair one member under two names.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

GENERATION_STEPS = 1_000_000  # an in-model generation's step: iteration × this + generation (``imagined_seed``)


class Stream(IntEnum):
    """The random streams; a stream's number is part of every seed drawn from it."""

    TRAINING = 0  # the real training episodes: a generation's candidates, an iteration's collected episodes
    MEASURING = 1  # the episodes the centre is measured on
    DEMONSTRATING = 2  # the demonstrator's episodes a model-free run's first centre is cloned from
    RESTARTING = 3  # each later attempt's search, with restart_every
    IMAGINING = 2  # a model-based run's imagined episodes: the in-model generations, the centres' promises
    FITTING = 3  # a model-based run's model fits: minibatches, held-out episodes, fresh initial weights
    EXPLORING = 4  # the imagined episodes that choose a model-based run's optimistic explorers
    SEEING = 5  # the frame autoencoder's fits, on frames
    EVALUATING = 6  # the episodes `drrl eval` measures a run's centre on, apart from every training run's
    BENCHMARKING = 7  # the fresh episodes a benchmark measures a trained policy on (benchmarks/stacking_cloned.py)


def derive_seed(seed: int, step: int, stream: Stream) -> int:
    """A seed that depends only on the run seed, the step (generation, iteration or attempt) and the stream; the
    steps from ``GENERATION_STEPS`` on of ``IMAGINING`` are the in-model generations' (``imagined_seed``)."""
    if stream == Stream.IMAGINING and step >= GENERATION_STEPS:
        raise ValueError(f"step {step} of the imagining stream is an in-model generation's: use imagined_seed")
    return _seed(seed, step, stream)


def imagined_seed(seed: int, iteration: int, generation: int) -> int:
    """The seed of in-model generation ``generation`` (1, 2, …) of model-based iteration ``iteration``: the
    ``IMAGINING`` stream at step iteration × ``GENERATION_STEPS`` + generation, above every step ``derive_seed``
    gives that stream (the iteration's own imagined episodes, at step ``iteration``)."""
    if not (iteration >= 1 and 1 <= generation < GENERATION_STEPS):
        raise ValueError(f"iteration {iteration}, generation {generation}: an in-model generation counts from 1 to 1e6")
    return _seed(seed, iteration * GENERATION_STEPS + generation, Stream.IMAGINING)


def _seed(seed: int, step: int, stream: Stream) -> int:
    return int(np.random.SeedSequence([seed, step, int(stream)]).generate_state(1)[0])
