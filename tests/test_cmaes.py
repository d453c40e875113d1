import math
import warnings

import pytest
import torch

from drrl.runs import RunFolder
from drrl.search.cmaes import CMAES

N = 10
_generator = torch.Generator().manual_seed(0)
TARGET = torch.rand(N, generator=_generator, dtype=torch.float64) * 2 - 1
ROTATION, _ = torch.linalg.qr(torch.randn(N, N, generator=_generator, dtype=torch.float64))
AXIS_SCALES = torch.logspace(0, 3, N, dtype=torch.float64)  # condition number 1e6


def sphere(x: torch.Tensor) -> torch.Tensor:
    return -((x.double() - TARGET) ** 2).sum(1)


def rotated_ellipsoid(x: torch.Tensor) -> torch.Tensor:
    return -(((x.double() - TARGET) @ ROTATION.T * AXIS_SCALES) ** 2).sum(1)


def run(search: CMAES, fitness, generations: int) -> float:
    """Run the search; the distance of its center from TARGET."""
    for _ in range(generations):
        search.tell(fitness(search.ask()))
    return float((search.center.double() - TARGET).norm())


# ------------------------------------------------------------------------------------------------- optimisation
@pytest.mark.parametrize("separable", [False, True])
def test_both_variants_find_the_maximum_of_a_sphere(separable):
    search = CMAES(torch.zeros(N), popsize=10, separable=separable, seed=1)
    assert run(search, sphere, 200) < 1e-3  # about 100 generations are needed


def test_full_covariance_solves_a_rotated_ill_conditioned_quadratic_where_the_diagonal_fails():
    full = CMAES(torch.zeros(N), popsize=10, seed=1)
    separable = CMAES(torch.zeros(N), popsize=10, separable=True, seed=1)
    assert run(full, rotated_ellipsoid, 600) < 1e-3  # about 350 generations are needed
    assert run(separable, rotated_ellipsoid, 600) > 0.1  # a diagonal C cannot follow rotated axes


def test_ask_tell_and_spread():
    center = torch.linspace(-1, 1, N)
    search = CMAES(center, popsize=6, sigma_init=0.3)
    assert torch.equal(search.center, center)
    torch.testing.assert_close(search.spread, torch.full((N,), 0.3))
    candidates = search.ask()
    assert candidates.shape == (6, N) and candidates.dtype == torch.float32
    metrics = search.tell(sphere(candidates))
    assert search.generation == 1
    assert metrics["step_size"] > 0 and metrics["best"] == pytest.approx(float(sphere(candidates).max()))
    assert torch.equal(search.sigma, search.spread)
    assert not torch.equal(search.center, center)


# ----------------------------------------------------------------------------------------------------- state
def continue_run(search: CMAES, generations: int) -> list:
    """The asks, centres and spreads of further generations on the sphere, then the whole state: float32 outputs
    alone could hide float64 differences in the last bits."""
    seen = []
    for _ in range(generations):
        candidates = search.ask()
        search.tell(sphere(candidates))
        seen += [candidates, search.center, search.spread]
    return [*seen, search.state_dict()]


def assert_same(a, b) -> None:
    """Bitwise equality of nested states (bytes, so that NaN in cmaes's uninitialised buffers compares equal)."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape
        assert a.cpu().numpy().tobytes() == b.cpu().numpy().tobytes()
    elif isinstance(a, (dict, list)):
        assert type(a) is type(b) and len(a) == len(b)
        for x, y in zip(a.values(), b.values(), strict=True) if isinstance(a, dict) else zip(a, b, strict=True):
            assert_same(x, y)
        assert not isinstance(a, dict) or list(a) == list(b)
    else:
        assert a == b and type(a) is type(b)


@pytest.mark.parametrize("separable", [False, True])
@pytest.mark.parametrize("between_ask_and_tell", [False, True])
def test_restored_search_continues_bit_identically(separable, between_ask_and_tell, tmp_path):
    settings = dict(popsize=8, sigma_init=0.5, separable=separable, seed=3)
    search = CMAES(torch.zeros(N), **settings)
    continue_run(search, 3)
    pending = search.ask() if between_ask_and_tell else None
    state = search.state_dict()
    folder = RunFolder(tmp_path)
    folder.save_checkpoint({"search": state})  # plain values and tensors only: no pickle

    if pending is not None:
        search.tell(sphere(pending))
    original = continue_run(search, 5)  # also proves the state does not share arrays with the running search

    for restored_state in (state, folder.load_checkpoint()["search"]):
        restored = CMAES(torch.ones(N), **settings)
        restored.load_state_dict(restored_state)
        assert restored.generation == 3
        if pending is not None:
            restored.tell(sphere(pending))  # the pending candidates were kept
        assert_same(continue_run(restored, 5), original)


def test_state_holds_only_checkpointable_values():
    search = CMAES(torch.zeros(N), popsize=8)
    search.ask()

    def check(value):
        if isinstance(value, dict):
            return all(isinstance(k, str) and check(v) for k, v in value.items())
        return value is None or isinstance(value, (torch.Tensor, bool, int, float, str))

    state = search.state_dict()
    assert check(state) and "pending" in state
    assert state["optimizer"]["_C"].dtype == torch.float64


@pytest.mark.parametrize(
    "other, message",
    [
        (dict(popsize=10), "popsize=8"),
        (dict(popsize=8, separable=True), "separable=False"),
    ],
)
def test_state_refuses_a_search_with_other_settings(other, message):
    state = CMAES(torch.zeros(N), popsize=8).state_dict()
    with pytest.raises(ValueError, match=message):
        CMAES(torch.zeros(N), **other).load_state_dict(state)


def test_state_refuses_another_kind_of_state():
    state = {**CMAES(torch.zeros(N), popsize=8).state_dict(), "kind": "pgpe"}
    with pytest.raises(ValueError, match="kind"):
        CMAES(torch.zeros(N), popsize=8).load_state_dict(state)
    del state["rng_state"]
    state["kind"] = "cmaes"
    with pytest.raises(ValueError, match="lacks rng_state"):
        CMAES(torch.zeros(N), popsize=8).load_state_dict(state)


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    "center, settings, message",
    [
        (torch.zeros(2, 2), {}, "1-D"),
        (torch.zeros(0), {}, "non-empty"),
        (torch.tensor([0.0, math.nan]), {}, "finite"),
        (torch.tensor([0.0, 1e33], dtype=torch.float64), {}, "below 1e\\+32"),
        (torch.zeros(1), dict(separable=True), "at least 2 parameters"),
        (torch.zeros(3), dict(separable=1), "separable"),
        (torch.zeros(3), dict(popsize=1), "popsize must be an integer >= 2"),
        (torch.zeros(3), dict(popsize=4.0), "popsize"),
        (torch.zeros(3), dict(popsize=True), "popsize"),
        (torch.zeros(3), dict(sigma_init=0.0), "sigma_init"),
        (torch.zeros(3), dict(sigma_init=math.inf), "sigma_init"),
        (torch.zeros(3), dict(seed=-1), "seed"),
        (torch.zeros(3), dict(seed=1.5), "seed"),
    ],
)
def test_bad_settings_are_refused_with_what_is_allowed(center, settings, message):
    with pytest.raises(ValueError, match=message):
        CMAES(center, **{"popsize": 4, **settings})


def test_small_populations_work_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for popsize in (2, 3):
            search = CMAES(torch.zeros(3), popsize=popsize)
            search.ask()
            search.tell(torch.arange(popsize, dtype=torch.float32))
            assert torch.isfinite(search.center).all() and torch.isfinite(search.spread).all()


def test_tell_needs_an_ask_first_and_tells_each_ask_once():
    search = CMAES(torch.zeros(3), popsize=4)
    with pytest.raises(RuntimeError, match="ask"):
        search.tell(torch.zeros(4))
    search.tell(-search.ask().square().sum(1))
    with pytest.raises(RuntimeError, match="ask"):
        search.tell(torch.zeros(4))


def test_bad_fitness_is_refused_and_leaves_the_search_untouched():
    search = CMAES(torch.zeros(3), popsize=4)
    search.ask()
    before = search.state_dict()
    with pytest.raises(ValueError, match="shape"):
        search.tell(torch.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        search.tell(torch.tensor([0.0, math.nan, 1.0, 2.0]))
    after = search.state_dict()
    assert search.generation == 0 and torch.equal(before["optimizer"]["_mean"], after["optimizer"]["_mean"])
    assert torch.equal(before["pending"], after["pending"])
