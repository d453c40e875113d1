"""PGPE, policy gradients with parameter-based exploration (thesis 2.4, Algorithm 2), as ask/tell.

Every parameter θ_i has its own Gaussian N(μ_i, σ_i²) (2.15). A generation asks for P candidates drawn around μ,
is told their fitness (returns, higher is better) and moves μ and σ along a likelihood-ratio gradient estimate.
The search never sees an environment: where the returns come from is the caller's business.

Samplers
    "single"          θ_p ~ N(μ, σ²), p = 1..P; 2.28–2.29 with the baseline b of 2.33.
    "symmetric"       SyS: pairs μ ± ε, ε ~ N(0, σ²); 2.31–2.32 with the baseline b of 2.33 (the thesis's choice).
    "supersymmetric"  SupSyS (Sehnke 2013, the thesis's ref. [21]): quadruples μ ± ε, μ ± ε*, where ε* mirrors ε
                      about the median of |ε|; the σ step compares the two pairs and needs no baseline.

Candidate layout: "symmetric" asks (μ+ε_1, μ-ε_1, μ+ε_2, μ-ε_2, ...); "supersymmetric" asks
(μ+ε_1, μ-ε_1, μ+ε*_1, μ-ε*_1, μ+ε_2, ...); fitness is told in the same order.

Departures from the thesis, and why
    * 2.26 and 2.28 carry a sign typo: ∇_μ log N(θ | μ, σ²) = (θ − μ)/σ², not (μ − θ)/σ². With the typo
      REINFORCE would descend.
    * "single" scales the likelihood-ratio gradient by σ², as Sehnke et al. 2008/2010 (ref. [22]) do: with
      t = θ − μ and s = (t² − σ²)/σ, Δμ = α mean_p (r_p − b) t_p and Δσ = α_σ mean_p (r_p − b) s_p. This is 2.28–2.29
      times σ², which puts them on the same footing as 2.31–2.32 (a natural-gradient-like step for a diagonal
      Gaussian).
    * The thesis writes 2.31–2.33 for one pair; with P/2 pairs we average over the pairs.
    * 2.33 is applied before the update (Algorithm 2, step 6): b ← decay · b + (1 − decay) · r̄, r̄ the generation's
      mean fitness (= the mean over pairs of (r⁺ + r⁻)/2), decay = 0.1 as in the thesis. There is no previous b on
      the first tell, so b starts at that generation's mean. "supersymmetric" tracks b for the metrics only.
    * The σ step of 2.32 is bounded to keep σ positive: σ ← σ · clamp(1 + Δσ/σ, 1 − c, 1 + c), c = max_sigma_change.
      The thesis leaves σ unbounded, and a plain step can make it negative.
    * The μ step may go through Adam or ClipUp instead of plain gradient ascent ("sgd", the thesis).
    * "supersymmetric" is not in the thesis; see ``mirror_about_median`` and
      ``_supersymmetric_sigma_gradient`` for how it was reconstructed.
    * Flat fitness: when every candidate of a generation earned the same return (e.g. every one drives its action
      to the same bound, so all fail alike), the estimate is zero and μ and σ would never move again. μ then stays
      and σ grows by the largest step allowed, σ ← σ · (1 + c), until the candidates differ, as CMA-ES does on flat
      fitness (Hansen, "The CMA Evolution Strategy: A Tutorial"), but to at most ``FLAT_FITNESS_SIGMA_LIMIT`` times
      σ₀: a task that pays nothing until a goal is found (FrozenLake, MountainCar) would otherwise widen σ for as
      long as no candidate finds it, beyond where μ's steps could ever matter again. The generation's metrics say
      "tied".
    * With fitness shaping, every formula sees the shaped values. Centred ranks sum to zero, so b, initialised to
      their mean, stays 0: SyS with centred ranks has the natural baseline 0.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import torch

from drrl.search.base import Search
from drrl.search.optimizers import OPTIMIZERS, make_optimizer
from drrl.search.shaping import FITNESS_SHAPINGS, shape_fitness

__all__ = ["FITNESS_SHAPINGS", "OPTIMIZERS", "PGPE", "SAMPLERS", "mirror_about_median"]

SAMPLERS = ("single", "symmetric", "supersymmetric")
CANDIDATES_PER_DRAW = {"single": 1, "symmetric": 2, "supersymmetric": 4}  # popsize must be a multiple

STATE_KEYS = {
    "sampler",
    "optimizer",
    "center",
    "sigma",
    "baseline",
    "has_baseline",
    "rng_state",
    "optimizer_state",
}  # plus "pending_noise" between an ask and its tell

FLAT_FITNESS_SIGMA_LIMIT = 100.0  # σ grows on flat fitness to at most this many times σ₀ (module docstring)
HALF_NORMAL_MEDIAN = 0.6744897501960817  # Φ⁻¹(3/4): the median of |ε| for ε ~ N(0, 1)
_MIRROR_C1, _MIRROR_C2, _MIRROR_C3 = -0.06655, -0.9706, 0.124  # Sehnke 2013's fit of the mirror map


def mirror_about_median(eps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """The super-symmetric partner ε* of ε ~ N(0, σ²) (Sehnke 2013), with the sign of ε.

    |ε*| mirrors |ε| about the median φ = 0.67449 σ of the half-normal distribution of |ε|, in probability:
    P(|X| < |ε*|) = 1 − P(|X| < |ε|) for X ~ N(0, σ²), so ε* has the same distribution as ε. The exact map needs
    the inverse error function; like the paper we use its closed-form approximation, with a = (φ − |ε|)/φ:

        |ε*| = φ · exp(a · (1 − c3 · log(1 − a³)))                   if a > 0   (|ε| below the median)
        |ε*| = φ · exp(|a| · (c1 · (a² − 1)/log|a| + c2))            if a ≤ 0   (|ε| above the median)

    c1 = −0.06655, c2 = −0.9706, c3 = 0.124. Against the exact mirror its error in probability is below 0.002
    everywhere (largest near |ε| = 0.3 σ); tests/test_pgpe.py checks this.

    Source: the paper's text was not at hand. The constants and the two-branch form come from a public
    implementation that cites it (pyRDDLGym-jax's PGPE), which writes a = (σ − |ε|)/σ; under that reading the
    median maps to 0.93 σ rather than to itself and the error in probability reaches 0.1. Under
    a = (φ − |ε|)/φ the fit reproduces the exact mirror as above, so that is the reading used here.
    """
    phi = HALF_NORMAL_MEDIAN * sigma
    a = (phi - eps.abs()) / phi  # in (-inf, 1]; 0 at the median
    size = a.abs()
    floor = torch.finfo(eps.dtype).eps  # |ε| → 0 would send |ε*| to infinity; this caps it near 20 φ
    below_median = size * (1 - _MIRROR_C3 * torch.log(torch.clamp(1 - size.pow(3), min=floor)))
    ratio = torch.where((size - 1).abs() < 1e-4, 2 * size, (size.square() - 1) / torch.log(size))  # 2 at |a| = 1
    above_median = size * (_MIRROR_C1 * ratio + _MIRROR_C2)
    return torch.sign(eps) * phi * torch.exp(torch.where(a > 0, below_median, above_median))


class PGPE(Search):
    """Ask/tell PGPE over a flat parameter vector, with state that saves and restores exactly.

    Args:
        center: initial μ, shape (n,). The search keeps a float32 copy on the same device.
        popsize: candidates per generation P; even for "symmetric", a multiple of 4 for "supersymmetric".
        sampler: one of ``SAMPLERS``.
        sigma_init: initial σ of every parameter.
        center_lr: step size of μ. For "sgd" it multiplies the gradient estimate, whose size is the fitness
            scale times σ² (2.31). Rough guides: raw returns spanning a few hundred (the thesis's cart-pole) with
            σ ≈ 1, about 1e-3 … 1e-2; "centered_ranks", about 0.1 … 2. For "adam" and "clipup" it is a step length
            in parameter units (e.g. 0.01 … 0.2), independent of the fitness scale.
        sigma_lr: step size of σ (2.32), plain gradient ascent; the same scale considerations as center_lr/sgd.
        optimizer: step rule for μ, one of ``OPTIMIZERS``; "sgd" is the thesis's plain gradient ascent.
        optimizer_options: extra keyword arguments of that optimizer (e.g. momentum, betas, max_speed).
        fitness_shaping: one of ``FITNESS_SHAPINGS``.
        baseline_decay: weight of the old baseline in 2.33 (the thesis: 0.1). Not used by "supersymmetric".
        max_sigma_change: bound c on the relative change of σ per generation, 0 < c < 1.
        seed: seed of the search's own random generator.
    """

    kind = "pgpe"

    def __init__(
        self,
        center: torch.Tensor,
        *,
        popsize: int,
        sampler: str = "symmetric",
        sigma_init: float = 1.0,
        center_lr: float = 0.01,
        sigma_lr: float = 0.005,
        optimizer: str = "sgd",
        optimizer_options: dict | None = None,
        fitness_shaping: str = "none",
        baseline_decay: float = 0.1,
        max_sigma_change: float = 0.2,
        seed: int = 0,
    ):
        center = torch.as_tensor(center)
        _check_settings(
            center,
            popsize,
            sampler,
            sigma_init,
            center_lr,
            sigma_lr,
            optimizer,
            optimizer_options,
            fitness_shaping,
            baseline_decay,
            max_sigma_change,
            seed,
        )
        super().__init__(center.numel(), popsize)
        self.sampler = sampler
        self.optimizer = optimizer
        self.fitness_shaping = fitness_shaping
        self.center_lr = center_lr
        self.sigma_lr = sigma_lr
        self.baseline_decay = baseline_decay
        self.max_sigma_change = max_sigma_change
        self.sigma_init = float(sigma_init)
        self._mu = center.detach().to(torch.float32).clone().requires_grad_(True)
        self._sigma = torch.full_like(self._mu.detach(), float(sigma_init))
        self._optimizer = make_optimizer(optimizer, [self._mu], center_lr, optimizer_options)
        self._generator = torch.Generator(device=self._mu.device)
        self._generator.manual_seed(int(seed))
        self._baseline = 0.0
        self._has_baseline = False
        self._noise: torch.Tensor | None = None  # the directions of the last ask, waiting for tell

    @property
    def center(self) -> torch.Tensor:
        """μ, shape (n,): a copy."""
        return self._mu.detach().clone()

    @property
    def sigma(self) -> torch.Tensor:
        """σ, shape (n,): a copy."""
        return self._sigma.clone()

    spread = sigma

    # ------------------------------------------------------------------ ask
    def ask(self) -> torch.Tensor:
        """P candidates, shape (popsize, n), in the layout of the module docstring. Asking again discards the
        previous candidates: the next tell refers to the latest ask."""
        mu = self._mu.detach()
        draws = self.popsize // CANDIDATES_PER_DRAW[self.sampler]
        eps = self._sigma * self._standard_normal(draws)
        if self.sampler == "single":
            self._noise = eps
            return mu + eps
        if self.sampler == "supersymmetric":
            eps = torch.stack([eps, mirror_about_median(eps, self._sigma)], dim=1).reshape(2 * draws, -1)
        self._noise = eps  # one row per symmetric pair: ε (and ε*)
        return torch.stack([mu + eps, mu - eps], dim=1).reshape(self.popsize, -1)

    def _standard_normal(self, rows: int) -> torch.Tensor:
        """(rows, n) standard normal draws from the search's generator (the one seam tests replace)."""
        return torch.randn(rows, self.num_params, generator=self._generator, device=self._mu.device)

    # ----------------------------------------------------------------- tell
    def _update(self, fitness: torch.Tensor) -> dict[str, float]:
        """Update μ and σ from the checked fitness. Metrics: "baseline" (the b of 2.33 used, on shaped values when
        shaping is on), "sigma_mean" (the new σ), "center_step_norm" (‖Δμ‖) and "tied" (1 when every
        candidate's fitness was the same, module docstring)."""
        if self._noise is None:
            raise RuntimeError("tell() needs candidates from ask() first (each ask is told once)")
        shaped = shape_fitness(fitness.to(self._mu.device), self.fitness_shaping)
        self._update_baseline(float(shaped.mean()))  # 2.33, before the update (Algorithm 2, step 6)
        old_mu = self._mu.detach().clone()
        tied = bool((fitness == fitness[0]).all())
        if tied:
            widest = FLAT_FITNESS_SIGMA_LIMIT * self.sigma_init
            self._sigma = torch.maximum(self._sigma, (self._sigma * (1 + self.max_sigma_change)).clamp(max=widest))
        else:
            grad_mu, grad_sigma = self._gradients(shaped, self._noise)
            self._step_center(grad_mu)
            self._step_sigma(grad_sigma)
        self._noise = None
        return {
            "baseline": self._baseline,
            "sigma_mean": float(self._sigma.mean()),
            "center_step_norm": float((self._mu.detach() - old_mu).norm()),
            "tied": float(tied),
        }

    def _update_baseline(self, mean: float) -> None:
        """2.33: b ← decay · b + (1 − decay) · mean fitness; on the first tell b starts at the mean."""
        if self._has_baseline:
            self._baseline = self.baseline_decay * self._baseline + (1 - self.baseline_decay) * mean
        else:
            self._baseline, self._has_baseline = mean, True

    def _gradients(self, r: torch.Tensor, eps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Ascent directions (g_μ, g_σ) for the sampler from the shaped fitness r of the last ask's directions eps;
        the steps are lr times these."""
        sigma, b = self._sigma, self._baseline
        if self.sampler == "single":  # 2.28–2.29, ×σ² (Sehnke et al.), sign typo fixed
            advantage = (r - b)[:, None]
            return (advantage * eps).mean(0), (advantage * (eps.square() - sigma.square()) / sigma).mean(0)
        pairs = r.view(-1, 2)  # (r⁺, r⁻) per row of eps
        grad_mu = (eps * ((pairs[:, 0] - pairs[:, 1]) / 2)[:, None]).mean(0)  # 2.31
        if self.sampler == "symmetric":
            advantage = (pairs.mean(1) - b)[:, None]
            return grad_mu, (advantage * (eps.square() - sigma.square()) / sigma).mean(0)  # 2.32
        return grad_mu, _supersymmetric_sigma_gradient(eps, pairs.mean(1), sigma)

    def _step_center(self, grad_mu: torch.Tensor) -> None:
        self._mu.grad = -grad_mu  # torch optimizers minimise
        self._optimizer.step()
        self._mu.grad = None

    def _step_sigma(self, grad_sigma: torch.Tensor) -> None:
        """σ ← σ · clamp(1 + Δσ/σ, 1 − c, 1 + c) with Δσ = sigma_lr · g_σ (2.32): positive and bounded."""
        ratio = 1 + self.sigma_lr * grad_sigma / self._sigma
        self._sigma = self._sigma * ratio.clamp(1 - self.max_sigma_change, 1 + self.max_sigma_change)

    # ---------------------------------------------------------------- state
    def _state(self) -> dict:
        optimizer_state = self._optimizer.state_dict()["state"].get(0, {})
        state = {
            "sampler": self.sampler,
            "optimizer": self.optimizer,
            "center": self.center,
            "sigma": self.sigma,
            "baseline": self._baseline,
            "has_baseline": self._has_baseline,
            "rng_state": self._generator.get_state(),
            "optimizer_state": {name: _copy(value) for name, value in optimizer_state.items() if value is not None},
        }
        if self._noise is not None:
            state["pending_noise"] = self._noise.clone()
        return state

    def _load_state(self, state: dict) -> None:
        missing = sorted(STATE_KEYS - set(state))
        if missing:
            raise ValueError(f"not a PGPE state: it lacks {', '.join(missing)}")
        for key in ("sampler", "optimizer"):
            if state.get(key) != getattr(self, key):
                raise ValueError(
                    f"state is for {key}={state.get(key)!r} but this PGPE has "
                    f"{key}={getattr(self, key)!r}; build it with the settings the state was saved with"
                )
        device = self._mu.device
        with torch.no_grad():
            self._mu.copy_(state["center"].to(device))
        self._sigma = state["sigma"].to(device=device, dtype=torch.float32).clone()
        self._baseline = float(state["baseline"])
        self._has_baseline = bool(state["has_baseline"])
        self._generator.set_state(state["rng_state"].cpu().to(torch.uint8))
        optimizer_state = {0: dict(state["optimizer_state"])} if state["optimizer_state"] else {}
        self._optimizer.load_state_dict(
            {"state": optimizer_state, "param_groups": self._optimizer.state_dict()["param_groups"]}
        )
        noise = state.get("pending_noise")
        self._noise = None if noise is None else noise.to(device=device, dtype=torch.float32).clone()


def _supersymmetric_sigma_gradient(eps: torch.Tensor, pair_means: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """SupSyS σ direction, baseline-free (Sehnke 2013).

    Per quadruple, the pair with the higher mean fitness r̄ wins; its exploration ε_w (ε or ε*) is rewarded
    against the other pair's mean, which takes the place of the baseline of 2.32:

        g_σ = mean_quadruples  (r̄_w − r̄_l)/2 · (ε_w² − σ²)/σ

    (r̄_w − r̄_l)/2 is |(r⁺ + r⁻) − (r*⁺ + r*⁻)|/4: the paper's reward term without its normalisation by the best
    reward, just as 2.32 is SyS without it. Our reading, as the paper was not at hand: the public implementation
    we read (pyRDDLGym-jax) multiplies the winner's term by the signed difference, which pushes σ away from |ε*|
    whenever the mirrored pair wins; with the magnitude, σ always moves towards the winner's |ε_w|.
    """
    eps = eps.view(-1, 2, eps.shape[-1])  # (quadruples, [ε, ε*], n)
    means = pair_means.view(-1, 2)
    first_wins = means[:, 0] >= means[:, 1]
    winner = torch.where(first_wins[:, None], eps[:, 0], eps[:, 1])
    weight = ((means[:, 0] - means[:, 1]).abs() / 2)[:, None]
    return (weight * (winner.square() - sigma.square()) / sigma).mean(0)


def _copy(value):
    return value.clone() if isinstance(value, torch.Tensor) else value


def check_whole_draws(sampler: str, popsize: int) -> None:
    """Refuse a ``popsize`` that is not a whole number of ``sampler``'s draws (the one rule, for the search and for a
    run's settings alike)."""
    if sampler == "symmetric" and popsize % 2:
        raise ValueError(f"symmetric sampling needs an even popsize (pairs μ ± ε), got {popsize}")
    if sampler == "supersymmetric" and popsize % 4:
        raise ValueError(f"supersymmetric sampling needs a popsize divisible by 4 (μ ± ε, μ ± ε*), got {popsize}")


def _check_settings(
    center,
    popsize,
    sampler,
    sigma_init,
    center_lr,
    sigma_lr,
    optimizer,
    optimizer_options,
    fitness_shaping,
    baseline_decay,
    max_sigma_change,
    seed,
) -> None:
    """Reject bad settings before any work, each with what was wrong and what is allowed."""
    for name, value, choices in (
        ("sampler", sampler, SAMPLERS),
        ("optimizer", optimizer, OPTIMIZERS),
        ("fitness_shaping", fitness_shaping, FITNESS_SHAPINGS),
    ):
        if value not in choices:
            raise ValueError(f"unknown {name} {value!r}; choose one of: {', '.join(choices)}")
    if center.dim() != 1 or center.numel() == 0:
        raise ValueError(
            f"center must be a non-empty 1-D tensor (one μ per parameter), got shape {tuple(center.shape)}"
        )
    if center.dtype == torch.bool or center.is_complex() or not bool(torch.isfinite(center.double()).all()):
        raise ValueError("center must hold finite real numbers")
    if isinstance(popsize, bool) or not isinstance(popsize, Integral) or popsize < 2:
        raise ValueError(f"popsize must be an integer >= 2, got {popsize!r}")
    check_whole_draws(sampler, int(popsize))
    for name, value in (("sigma_init", sigma_init), ("center_lr", center_lr), ("sigma_lr", sigma_lr)):
        if not (isinstance(value, Real) and math.isfinite(value) and float(value) > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    if not (isinstance(baseline_decay, Real) and 0 <= float(baseline_decay) <= 1):
        raise ValueError(
            f"baseline_decay (the old baseline's weight in 2.33) must be in [0, 1], got {baseline_decay!r}"
        )
    if not (isinstance(max_sigma_change, Real) and 0 < float(max_sigma_change) < 1):
        raise ValueError(f"max_sigma_change (bound on |Δσ/σ| per step) must be in (0, 1), got {max_sigma_change!r}")
    if not (optimizer_options is None or isinstance(optimizer_options, dict)):
        raise ValueError(f"optimizer_options must be a dict of keyword arguments or None, got {optimizer_options!r}")
    if isinstance(seed, bool) or not isinstance(seed, Integral):
        raise ValueError(f"seed must be an integer, got {seed!r}")
