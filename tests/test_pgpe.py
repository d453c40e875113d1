import math

import pytest
import torch

from drrl.search import FITNESS_SHAPINGS, OPTIMIZERS, PGPE, SAMPLERS, centered_ranks, mirror_about_median
from drrl.search.pgpe import FLAT_FITNESS_SIGMA_LIMIT, HALF_NORMAL_MEDIAN


def inject(pgpe: PGPE, *rows: list[float]) -> None:
    """Make the next ask use these standard-normal draws z (ε = σ z) instead of the generator's."""
    pgpe._standard_normal = lambda count: torch.tensor(rows[:count], dtype=torch.float32)


def close(actual: torch.Tensor, expected: list[float]) -> None:
    torch.testing.assert_close(actual, torch.tensor(expected, dtype=torch.float32), rtol=1e-5, atol=1e-6)


def half_normal_cdf(x: float, sigma: float) -> float:
    """P(|X| < x) for X ~ N(0, σ²)."""
    return math.erf(x / (sigma * math.sqrt(2)))


def paper_mirror(e: float, sigma: float) -> float:
    """Sehnke 2013's approximate mirror, in plain floats (a = (φ − |ε|)/φ)."""
    phi = HALF_NORMAL_MEDIAN * sigma
    a = (phi - abs(e)) / phi
    if a > 0:
        exponent = a * (1 - 0.124 * math.log(1 - a**3))
    else:
        exponent = abs(a) * (-0.06655 * (a * a - 1) / math.log(abs(a)) - 0.9706)
    return math.copysign(phi * math.exp(exponent), e)


# ------------------------------------------------------------------------------------------ hand-worked updates
def test_symmetric_step_follows_2_31_to_2_33_on_hand_worked_numbers():
    pgpe = PGPE(
        torch.tensor([1.0, -1.0]),
        popsize=4,
        sampler="symmetric",
        sigma_init=0.5,
        center_lr=0.1,
        sigma_lr=0.2,
        max_sigma_change=0.5,
    )
    inject(pgpe, [1.0, -2.0], [0.5, 1.0])  # ε_1 = (0.5, -1), ε_2 = (0.25, 0.5)
    close(pgpe.ask(), [[1.5, -2.0], [0.5, 0.0], [1.25, -0.5], [0.75, -1.5]])  # μ+ε_1, μ-ε_1, μ+ε_2, μ-ε_2

    metrics = pgpe.tell(torch.tensor([3.0, 1.0, -2.0, 2.0]))
    # first tell: b = mean reward = 1
    # 2.31: Δμ = 0.1 · mean(ε_1 (3-1)/2, ε_2 (-2-2)/2) = 0.1 · mean((0.5, -1), (-0.5, -1)) = (0, -0.1)
    # 2.32: pair means 2 and 0; (ε²-σ²)/σ = (0, 1.5) and (-0.375, 0)
    #       Δσ = 0.2 · mean((2-1)(0, 1.5), (0-1)(-0.375, 0)) = 0.2 · (0.1875, 0.75) = (0.0375, 0.15)
    assert metrics["baseline"] == pytest.approx(1.0)
    close(pgpe.center, [1.0, -1.1])
    close(pgpe.sigma, [0.5375, 0.65])
    assert metrics["center_step_norm"] == pytest.approx(0.1, rel=1e-5)
    assert (metrics["mean"], metrics["best"], metrics["worst"]) == (1.0, 3.0, -2.0)

    # second tell: 2.33 with the old baseline: b = 0.1 · 1 + 0.9 · mean(r) = 0.1 + 0.9 · 2.5 = 2.35
    inject(pgpe, [2.0, 0.0], [-1.0, 1.0])
    sigma, mu = [0.5375, 0.65], [1.0, -1.1]
    eps = [[s * z for s, z in zip(sigma, row, strict=True)] for row in ([2.0, 0.0], [-1.0, 1.0])]
    pgpe.ask()
    rewards = [4.0, 2.0, 1.0, 3.0]
    metrics = pgpe.tell(torch.tensor(rewards))
    b = 0.1 * 1.0 + 0.9 * 2.5
    pairs = [(4.0, 2.0), (1.0, 3.0)]
    step_mu = [0.1 * sum(e[i] * (rp - rm) / 2 for e, (rp, rm) in zip(eps, pairs, strict=True)) / 2 for i in range(2)]
    step_sigma = [
        0.2
        * sum(
            ((rp + rm) / 2 - b) * (e[i] ** 2 - sigma[i] ** 2) / sigma[i] for e, (rp, rm) in zip(eps, pairs, strict=True)
        )
        / 2
        for i in range(2)
    ]
    assert metrics["baseline"] == pytest.approx(b)
    close(pgpe.center, [m + d for m, d in zip(mu, step_mu, strict=True)])
    close(pgpe.sigma, [s + d for s, d in zip(sigma, step_sigma, strict=True)])


def test_reinforce_step_is_2_28_2_29_scaled_by_sigma_squared_with_the_sign_fixed():
    pgpe = PGPE(
        torch.zeros(2),
        popsize=2,
        sampler="single",
        sigma_init=0.5,
        center_lr=0.1,
        sigma_lr=0.2,
        max_sigma_change=0.5,
    )
    inject(pgpe, [1.0, 0.0], [-2.0, 1.0])  # t_1 = (0.5, 0), t_2 = (-1, 0.5)
    close(pgpe.ask(), [[0.5, 0.0], [-1.0, 0.5]])
    pgpe.tell(torch.tensor([4.0, 2.0]))
    # b = 3, advantages (1, -1)
    # Δμ = 0.1 · mean(1 · (0.5, 0), -1 · (-1, 0.5)) = 0.1 · (0.75, -0.25): towards the better candidate
    # s = (t²-σ²)/σ = (0, -0.5) and (1.5, 0); Δσ = 0.2 · mean((0, -0.5), (-1.5, 0)) = (-0.15, -0.05)
    close(pgpe.center, [0.075, -0.025])
    close(pgpe.sigma, [0.35, 0.45])


def test_supersymmetric_step_on_hand_worked_numbers():
    pgpe = PGPE(
        torch.zeros(1),
        popsize=8,
        sampler="supersymmetric",
        sigma_init=1.0,
        center_lr=0.1,
        sigma_lr=0.1,
        max_sigma_change=0.5,
    )
    inject(pgpe, [0.3], [-1.5])
    candidates = pgpe.ask()[:, 0].tolist()
    e1, e2 = 0.3, -1.5
    s1, s2 = paper_mirror(e1, 1.0), paper_mirror(e2, 1.0)
    assert candidates == pytest.approx([e1, -e1, s1, -s1, e2, -e2, s2, -s2], rel=1e-5)
    assert s1 == pytest.approx(1.1855, abs=0.01) and s2 == pytest.approx(-0.1687, abs=0.01)  # exact mirrors

    # quadruple 1: pair means 0.5 (ε) < 2 (ε*): ε* wins, weight |0.5-2|/2 = 0.75
    # quadruple 2: pair means 3 (ε) > 0 (ε*): ε wins, weight 1.5
    pgpe.tell(torch.tensor([1.0, 0.0, 3.0, 1.0, 2.0, 4.0, 0.0, 0.0]))
    step_mu = 0.1 * (e1 * 0.5 + s1 * 1.0 + e2 * -1.0 + s2 * 0.0) / 4  # 2.31 over all four pairs
    step_sigma = 0.1 * (0.75 * (s1**2 - 1) + 1.5 * (e2**2 - 1)) / 2
    close(pgpe.center, [step_mu])
    close(pgpe.sigma, [1.0 + step_sigma])


@pytest.mark.parametrize("sampler, uses_baseline", [("symmetric", True), ("supersymmetric", False)])
def test_only_supersymmetric_sampling_does_without_the_baseline(sampler, uses_baseline):
    sigmas = []
    for decay in (0.0, 1.0):  # b follows each generation's mean, or stays at the first one
        pgpe = PGPE(torch.zeros(3), popsize=8, sampler=sampler, baseline_decay=decay, seed=3)
        for generation in range(3):
            x = pgpe.ask()
            pgpe.tell(-(x - 1).square().sum(1) + 10.0 * generation)
        sigmas.append(pgpe.sigma)
    assert torch.equal(sigmas[0], sigmas[1]) != uses_baseline


def test_sigma_change_is_bounded_by_max_sigma_change():
    pgpe = PGPE(torch.zeros(2), popsize=4, sigma_init=1.0, sigma_lr=10.0, max_sigma_change=0.2)
    inject(pgpe, [3.0, 0.1], [0.1, 3.0])
    pgpe.ask()
    pgpe.tell(torch.tensor([110.0, 110.0, 70.0, 70.0]))  # first tell: b = 90, advantages +20 and -20
    # (ε² - σ²)/σ = (8, -0.99) and (-0.99, 8); Δσ = 10 · mean(20 · (8, -0.99), -20 · (-0.99, 8)) = (899, -899):
    # clamped to +20% and -20%, so σ stays positive
    close(pgpe.sigma, [1.2, 0.8])
    close(pgpe.center, [0.0, 0.0])  # r⁺ = r⁻ in both pairs


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_flat_fitness_keeps_the_centre_and_widens_sigma_by_the_largest_step(sampler):
    """Every candidate tied (no gradient): μ stays, σ grows by 1 + c until the candidates differ."""
    pgpe = PGPE(torch.ones(3), popsize=8, sampler=sampler, sigma_init=0.5, max_sigma_change=0.2, optimizer="adam")
    for generation in range(1, 4):
        pgpe.ask()
        metrics = pgpe.tell(torch.full((8,), -229.0))
        assert metrics["tied"] == 1.0 and metrics["center_step_norm"] == 0.0
        close(pgpe.center, [1.0, 1.0, 1.0])
        close(pgpe.sigma, [0.5 * 1.2**generation] * 3)
    pgpe.ask()
    metrics = pgpe.tell(torch.arange(8.0))
    assert metrics["tied"] == 0.0 and metrics["center_step_norm"] > 0


def test_flat_fitness_widens_sigma_no_further_than_its_limit():
    """A task that pays nothing for a long time: σ stops at FLAT_FITNESS_SIGMA_LIMIT · σ₀ (1.2²⁶ ≈ 114 > 100)."""
    pgpe = PGPE(torch.zeros(2), popsize=4, sigma_init=0.03, max_sigma_change=0.2, optimizer="clipup")
    for _ in range(60):
        pgpe.ask()
        pgpe.tell(torch.zeros(4))
    close(pgpe.sigma, [0.03 * FLAT_FITNESS_SIGMA_LIMIT] * 2)


# ------------------------------------------------------------------------------------- super-symmetric mirror
@pytest.mark.parametrize("sigma", [0.3, 1.0, 2.5])
def test_mirror_reflects_probability_about_the_half_normal_median(sigma):
    magnitudes = [sigma * (0.001 + 4.0 * i / 400) for i in range(401)]
    eps = torch.tensor(magnitudes + [-m for m in magnitudes], dtype=torch.float32)
    mirrored = mirror_about_median(eps, torch.full_like(eps, sigma))
    assert torch.equal(torch.sign(mirrored), torch.sign(eps))
    worst = max(
        abs(half_normal_cdf(abs(m), sigma) - (1 - half_normal_cdf(abs(e), sigma)))
        for e, m in zip(eps.tolist(), mirrored.tolist(), strict=True)
    )
    assert worst < 2.5e-3  # the paper's fit is within 0.002 of the exact mirror in probability
    median = torch.tensor([HALF_NORMAL_MEDIAN * sigma])
    close(mirror_about_median(median, torch.tensor([sigma])), [HALF_NORMAL_MEDIAN * sigma])


def test_mirrored_samples_keep_the_sampling_distribution():
    generator = torch.Generator().manual_seed(0)
    sigma = torch.full((200_000,), 0.7)
    mirrored = mirror_about_median(sigma * torch.randn(200_000, generator=generator), sigma)
    assert torch.isfinite(mirrored).all()
    assert mirrored.std().item() == pytest.approx(0.7, rel=0.01)
    assert mirrored.abs().median().item() == pytest.approx(HALF_NORMAL_MEDIAN * 0.7, rel=0.01)


def test_mirror_is_finite_at_zero_and_at_twice_the_median():
    sigma = torch.ones(3)
    mirrored = mirror_about_median(torch.tensor([0.0, 2 * HALF_NORMAL_MEDIAN, 1e-30]), sigma)
    assert torch.isfinite(mirrored).all()
    assert mirrored[1].item() == pytest.approx(paper_mirror(2 * HALF_NORMAL_MEDIAN + 1e-9, 1.0), rel=1e-4)


# ------------------------------------------------------------------------------------------------ convergence
TARGET = torch.tensor([0.5, -1.0, 1.5, 0.0, -0.5])
STEP = {
    "sgd": dict(center_lr=1.0, generations=150),
    "adam": dict(center_lr=0.1, generations=150),
    "clipup": dict(center_lr=0.01, generations=250),
}


@pytest.mark.parametrize("optimizer", OPTIMIZERS)
@pytest.mark.parametrize("sampler", SAMPLERS)
def test_every_sampler_and_optimizer_maximise_a_concave_quadratic(sampler, optimizer):
    settings = dict(STEP[optimizer])
    generations = settings.pop("generations")
    pgpe = PGPE(
        torch.zeros(5),
        popsize=32,
        sampler=sampler,
        optimizer=optimizer,
        sigma_init=0.5,
        sigma_lr=0.05,
        seed=0,
        **settings,
    )
    for _ in range(generations):
        x = pgpe.ask()
        pgpe.tell(-(x - TARGET).square().sum(1))
    assert (pgpe.center - TARGET).norm() < 0.1  # from 1.94 away
    assert pgpe.sigma.max() < 0.5  # exploration shrank near the optimum


def test_centered_ranks_converge_with_a_zero_baseline():
    pgpe = PGPE(
        torch.zeros(5),
        popsize=16,
        fitness_shaping="centered_ranks",
        sigma_init=0.5,
        center_lr=2.0,
        sigma_lr=0.5,
        seed=0,
    )
    for _ in range(150):
        x = pgpe.ask()
        metrics = pgpe.tell(-1000 * (x - TARGET).square().sum(1) - 123.0)  # scale and offset do not matter
        assert abs(metrics["baseline"]) < 1e-6
    assert (pgpe.center - TARGET).norm() < 0.1


# ------------------------------------------------------------------------------------------------ fitness shaping
def test_centered_ranks_span_minus_half_to_half_and_average_ties():
    close(centered_ranks(torch.tensor([10.0, -3.0, 7.0, 0.5, 2.0])), [0.5, -0.5, 0.25, -0.25, 0.0])
    # 5 and 5 share ranks 2 and 3 → 2.5 → 2.5/4 - 0.5 = 0.125
    shaped = centered_ranks(torch.tensor([5.0, 1.0, 5.0, 9.0, -2.0]))
    close(shaped, [0.125, -0.25, 0.125, 0.5, -0.5])
    assert shaped.sum().abs() < 1e-6


# ----------------------------------------------------------------------------------------------------- state
def assert_plain(value, where="state"):
    """Only tensors, bools/ints/floats/strs, and dicts (str keys) / lists of them."""
    if isinstance(value, dict):
        for key, item in value.items():
            assert isinstance(key, str), f"{where} has a non-string key {key!r}"
            assert_plain(item, f"{where}[{key!r}]")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            assert_plain(item, f"{where}[{index}]")
    else:
        assert isinstance(value, (torch.Tensor, bool, int, float, str)), f"{where} is a {type(value).__name__}"


def quadratic(x: torch.Tensor) -> torch.Tensor:
    return -(x - TARGET).square().sum(1)


@pytest.mark.parametrize("optimizer", OPTIMIZERS)
@pytest.mark.parametrize("sampler", SAMPLERS)
def test_restored_search_continues_bit_identically(sampler, optimizer):
    settings = dict(popsize=8, sampler=sampler, optimizer=optimizer, center_lr=0.05, sigma_lr=0.05)
    original = PGPE(torch.zeros(5), seed=1, **settings)
    for _ in range(4):
        original.tell(quadratic(original.ask()))
    state = original.state_dict()
    assert_plain(state)
    assert state["rng_state"].dtype == torch.uint8
    asks, centers = [], []
    for _ in range(4):  # the original runs on; the saved state must not change with it
        asks.append(original.ask())
        original.tell(quadratic(asks[-1]))
        centers.append(original.center)

    restored = PGPE(torch.ones(5), seed=99, **settings)
    restored.load_state_dict(state)
    for ask, center in zip(asks, centers, strict=True):
        candidates = restored.ask()
        assert torch.equal(candidates, ask)
        restored.tell(quadratic(candidates))
        assert torch.equal(restored.center, center)
    assert torch.equal(restored.sigma, original.sigma)
    assert restored.generation == original.generation == 8


def test_state_saved_between_ask_and_tell_keeps_the_pending_candidates():
    original = PGPE(torch.zeros(3), popsize=4, seed=5)
    candidates = original.ask()
    state = original.state_dict()
    assert_plain(state)
    original.tell(quadratic(torch.cat([candidates, torch.zeros(4, 2)], 1)))
    restored = PGPE(torch.zeros(3), popsize=4, seed=6)
    restored.load_state_dict(state)
    restored.tell(quadratic(torch.cat([candidates, torch.zeros(4, 2)], 1)))
    assert torch.equal(restored.center, original.center) and torch.equal(restored.sigma, original.sigma)
    assert torch.equal(restored.ask(), original.ask())


def test_state_refuses_a_search_with_other_settings():
    state = PGPE(torch.zeros(3), popsize=4).state_dict()
    with pytest.raises(ValueError, match=r"sampler='symmetric'.*sampler='single'"):
        PGPE(torch.zeros(3), popsize=4, sampler="single").load_state_dict(state)
    with pytest.raises(ValueError, match="num_params"):
        PGPE(torch.zeros(4), popsize=4).load_state_dict(state)


# ------------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "settings, message",
    [
        (
            dict(sampler="antithetic"),
            "unknown sampler 'antithetic'; choose one of: single, symmetric, supersymmetric",
        ),
        (dict(optimizer="rmsprop"), "unknown optimizer 'rmsprop'; choose one of: sgd, adam, clipup"),
        (dict(fitness_shaping="ranks"), "unknown fitness_shaping 'ranks'; choose one of: none, centered_ranks"),
        (dict(sigma_init=0.0), "sigma_init must be a positive finite number, got 0.0"),
        (dict(sigma_init=-1.0), "sigma_init must be a positive finite number"),
        (dict(sigma_init=math.nan), "sigma_init must be a positive finite number"),
        (dict(sigma_init=math.inf), "sigma_init must be a positive finite number"),
        (dict(center_lr=0.0), "center_lr must be a positive finite number"),
        (dict(sigma_lr=-0.1), "sigma_lr must be a positive finite number"),
        (dict(popsize=1), "popsize must be an integer >= 2, got 1"),
        (dict(popsize=4.0), "popsize must be an integer >= 2"),
        (dict(popsize=7), "symmetric sampling needs an even popsize \\(pairs μ ± ε\\), got 7"),
        (dict(popsize=6, sampler="supersymmetric"), "supersymmetric sampling needs a popsize divisible by 4 .*, got 6"),
        (dict(baseline_decay=1.5), "baseline_decay .* must be in \\[0, 1\\]"),
        (dict(max_sigma_change=1.0), "max_sigma_change .* must be in \\(0, 1\\)"),
        (dict(optimizer_options={"lr": 0.1}), "does not take option\\(s\\) 'lr'; it accepts: momentum, dampening"),
        (dict(optimizer="clipup", optimizer_options={"betas": (0.9, 0.99)}), "it accepts: momentum, max_speed"),
        (dict(center=torch.zeros(2, 3)), "center must be a non-empty 1-D tensor"),
        (dict(center=torch.zeros(0)), "center must be a non-empty 1-D tensor"),
        (dict(center=torch.tensor([0.0, math.nan])), "center must hold finite real numbers"),
    ],
)
def test_bad_settings_are_refused_with_what_is_allowed(settings, message):
    arguments = dict(center=torch.zeros(3), popsize=8) | settings
    with pytest.raises(ValueError, match=message):
        PGPE(arguments.pop("center"), **arguments)


def test_tell_needs_an_ask_first_and_tells_each_ask_once():
    pgpe = PGPE(torch.zeros(3), popsize=4)
    with pytest.raises(RuntimeError, match="ask"):
        pgpe.tell(torch.zeros(4))
    pgpe.ask()
    pgpe.tell(torch.zeros(4))
    with pytest.raises(RuntimeError, match="ask"):
        pgpe.tell(torch.zeros(4))


def test_fitness_of_the_wrong_shape_is_refused():
    pgpe = PGPE(torch.zeros(3), popsize=4)
    pgpe.ask()
    with pytest.raises(ValueError, match=r"shape \(4,\).*got shape \(2, 2\)"):
        pgpe.tell(torch.zeros(2, 2))


def test_non_finite_fitness_names_the_candidates_and_leaves_the_search_untouched():
    pgpe = PGPE(torch.zeros(3), popsize=4)
    candidates = pgpe.ask()
    with pytest.raises(ValueError, match=r"candidate index\(es\) 1, 3 are NaN or infinite"):
        pgpe.tell(torch.tensor([0.0, math.nan, 1.0, -math.inf]))
    assert torch.equal(pgpe.center, torch.zeros(3)) and pgpe.generation == 0
    pgpe.tell(quadratic(torch.cat([candidates, torch.zeros(4, 2)], 1)))  # the same ask can still be told
    assert pgpe.generation == 1


def test_names_are_exported_for_the_command_line():
    assert SAMPLERS == ("single", "symmetric", "supersymmetric")
    assert OPTIMIZERS == ("sgd", "adam", "clipup")
    assert FITNESS_SHAPINGS == ("none", "centered_ranks")
