"""CMA-ES, the covariance matrix adaptation evolution strategy, as ask/tell over the package ``cmaes``.

Candidates are drawn from N(m, σ² C). Each generation moves the mean m towards the better candidates, adapts the
global step size σ along an evolution path, and learns the covariance C from successful steps (Hansen &
Ostermeier 2001, "Completely derandomized self-adaptation in evolution strategies"). ``separable=True`` keeps only
the diagonal of C (sep-CMA-ES, Ros & Hansen 2008): O(n) per candidate instead of O(n²), for policies of thousands of
weights. The algorithm is ``cmaes.CMA`` / ``cmaes.SepCMA``; this module only adapts it to ``Search``.

Why it is here
    CMA-ES is not in the thesis. It is the reference searcher that users of peer libraries (EvoTorch, evosax)
    expect to compare against, and a second implementation of the search interface next to PGPE.

Differences from PGPE and from cmaes's defaults
    * The PGPE settings (sampler, optimizer, center_lr, sigma_lr, fitness shaping) do not apply: CMA-ES sets its
      own learning rates and uses only the ranking of the fitness.
    * cmaes's default population is 4 + ⌊3 ln n⌋; drrl uses the configured popsize.
    * cmaes minimises, so it is told the negated fitness.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import cmaes
import numpy as np
import torch

from drrl.search.base import Search

__all__ = ["CMAES"]

MAX_ABS = 1e32  # cmaes asserts |mean| and |candidate| below this
STATE_KEYS = {"separable", "optimizer", "rng_state"}  # plus "pending" between an ask and its tell


class CMAES(Search):
    """Ask/tell CMA-ES over a flat parameter vector, with state that saves and restores exactly.

    Args:
        center: initial mean m, shape (n,). Candidates are float32 tensors on its device.
        popsize: candidates per generation, at least 2.
        sigma_init: initial global step size σ (C starts as the identity).
        separable: diagonal C (``cmaes.SepCMA``, needs n >= 2) instead of full C (``cmaes.CMA``).
        seed: seed of the optimizer's random generator, 0 <= seed < 2**32.
    """

    kind = "cmaes"

    def __init__(
        self, center: torch.Tensor, *, popsize: int, sigma_init: float = 1.0, separable: bool = False, seed: int = 0
    ):
        center = torch.as_tensor(center)
        _check_settings(center, popsize, sigma_init, separable, seed)
        super().__init__(center.numel(), popsize)
        self.separable = bool(separable)
        self._device = center.device
        mean = center.detach().cpu().to(torch.float64).numpy().copy()
        optimizer_class = cmaes.SepCMA if self.separable else cmaes.CMA
        with np.errstate(divide="ignore"):  # CMA divides by a zero rank-μ rate for popsize < 4, harmlessly
            self._optimizer = optimizer_class(
                mean=mean, sigma=float(sigma_init), seed=int(seed), population_size=self.popsize
            )
        self._asked: np.ndarray | None = None  # the float64 candidates of the last ask, waiting for tell

    @property
    def center(self) -> torch.Tensor:
        """The mean m, shape (n,): a copy."""
        return self._to_torch(self._optimizer.mean)

    @property
    def spread(self) -> torch.Tensor:
        """σ · sqrt(diag C), the standard deviation per parameter, shape (n,): a copy."""
        variances = self._optimizer._C if self.separable else np.diag(self._optimizer._C)
        return self._to_torch(self._optimizer._sigma * np.sqrt(np.maximum(variances, 0.0)))

    sigma = spread

    def ask(self) -> torch.Tensor:
        """popsize candidates, shape (popsize, n). Asking again discards the previous candidates: the next tell
        refers to the latest ask."""
        self._asked = np.stack([self._optimizer.ask() for _ in range(self.popsize)])
        return self._to_torch(self._asked)

    def _update(self, fitness: torch.Tensor) -> dict[str, float]:
        """Tell cmaes the asked candidates with the negated fitness. Metrics: "step_size" (the new σ)."""
        if self._asked is None:
            raise RuntimeError("tell() needs candidates from ask() first (each ask is told once)")
        if not np.all(np.abs(self._asked) < MAX_ABS):
            raise RuntimeError(
                f"the search diverged: asked candidates reach |x| >= {MAX_ABS:g}, which cmaes refuses to be told"
            )
        self._optimizer.tell([(x, -f) for x, f in zip(self._asked, fitness.tolist(), strict=True)])
        self._asked = None
        return {"step_size": float(self._optimizer._sigma)}

    def _to_torch(self, array: np.ndarray) -> torch.Tensor:
        return torch.tensor(array, dtype=torch.float32, device=self._device)

    # ---------------------------------------------------------------- state
    def _state(self) -> dict:
        attrs = self._optimizer.__getstate__()
        if "_c_1d" in attrs:  # CMA packs one triangle of C, but C is symmetric only up to rounding: keep it whole
            del attrs["_c_1d"]
            attrs["_C"] = self._optimizer._C
        name, keys, pos, has_gauss, cached_gaussian = self._optimizer._rng.get_state()
        state = {
            "separable": self.separable,
            "optimizer": {key: _plain(value) for key, value in attrs.items()},
            "rng_state": {
                "name": name,
                "keys": torch.from_numpy(keys.astype(np.int64)),
                "pos": int(pos),
                "has_gauss": int(has_gauss),
                "cached_gaussian": float(cached_gaussian),
            },
        }
        if self._asked is not None:
            state["pending"] = torch.from_numpy(self._asked.copy())
        return state

    def _load_state(self, state: dict) -> None:
        missing = sorted(STATE_KEYS - set(state))
        if missing:
            raise ValueError(f"not a CMA-ES state: it lacks {', '.join(missing)}")
        if state["separable"] != self.separable:
            raise ValueError(
                f"state is for separable={state['separable']!r} but this CMA-ES has "
                f"separable={self.separable!r}; build it with the settings the state was saved with"
            )
        attrs = {key: _numpy(value) for key, value in state["optimizer"].items()}
        covariance = attrs["_C"]
        if not self.separable:  # what CMA.__setstate__ unpacks; the exact C is put back below
            attrs["_c_1d"] = covariance[np.triu_indices(len(covariance))]
        self._optimizer.__setstate__(attrs)
        self._optimizer._C = covariance
        rng = state["rng_state"]
        self._optimizer._rng.set_state(
            (
                rng["name"],
                _numpy(rng["keys"]).astype(np.uint32),
                int(rng["pos"]),
                int(rng["has_gauss"]),
                float(rng["cached_gaussian"]),
            )
        )
        pending = state.get("pending")
        self._asked = None if pending is None else _numpy(pending)


def _plain(value):
    """A cmaes attribute as a checkpointable value: arrays as tensors (dtype kept), numpy scalars as Python ones."""
    if isinstance(value, np.ndarray):
        return torch.from_numpy(value.copy())
    if isinstance(value, np.generic):
        return value.item()
    return value


def _numpy(value):
    """Inverse of ``_plain``: tensors as fresh numpy arrays (cmaes updates its arrays in place)."""
    return value.detach().cpu().numpy().copy() if isinstance(value, torch.Tensor) else value


def _check_settings(center, popsize, sigma_init, separable, seed) -> None:
    """Reject bad settings before any work, each with what was wrong and what is allowed (instead of cmaes's
    assertions)."""
    if center.dim() != 1 or center.numel() == 0:
        raise ValueError(
            f"center must be a non-empty 1-D tensor (one mean per parameter), got shape {tuple(center.shape)}"
        )
    if center.dtype == torch.bool or center.is_complex() or not bool(torch.isfinite(center.double()).all()):
        raise ValueError("center must hold finite real numbers")
    if not bool((center.double().abs() < MAX_ABS).all()):
        raise ValueError(f"cmaes needs every element of center below {MAX_ABS:g} in absolute value")
    if not isinstance(separable, bool):
        raise ValueError(f"separable must be True or False, got {separable!r}")
    if separable and center.numel() < 2:
        raise ValueError("separable CMA-ES (cmaes.SepCMA) needs at least 2 parameters; use separable=False")
    if isinstance(popsize, bool) or not isinstance(popsize, Integral) or popsize < 2:
        raise ValueError(f"popsize must be an integer >= 2, got {popsize!r}")
    if isinstance(sigma_init, bool) or not (
        isinstance(sigma_init, Real) and math.isfinite(sigma_init) and 0 < float(sigma_init) < MAX_ABS
    ):
        raise ValueError(f"sigma_init must be a positive finite number below {MAX_ABS:g}, got {sigma_init!r}")
    if isinstance(seed, bool) or not isinstance(seed, Integral) or not 0 <= int(seed) < 2**32:
        raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
