"""The Ray backend on a local two-CPU Ray, started once for the module: same numbers as the local backend."""

import csv
import os
import signal
import time

import pytest
import torch
from click.testing import CliRunner

from drrl.cli import main
from drrl.policies import make_policy
from drrl.rollout import Workload, make_backend

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.mark.slow
def test_more_workers_than_cpus_are_refused():
    workload = Workload(make_policy("linear", 4, 1), "drrl/CartPole-v0", popsize=8, episodes=1)
    with pytest.raises(ValueError, match=r"3 Ray worker\(s\) need as many CPUs, but the Ray cluster has 2"):
        make_backend("ray", workload, workers=3)
    assert ray.is_initialized()  # a Ray the backend did not start is left running


def test_drrl_train_with_the_ray_backend_writes_the_local_backend_s_metrics(tmp_path):
    args = ["train", "cartpole", "--budget", "32", "--popsize", "8", "--eval-episodes", "3", "--seed", "2", "--quiet"]
    runner = CliRunner()
    local = runner.invoke(main, [*args, "--out", str(tmp_path / "local")])
    remote = runner.invoke(main, [*args, "--out", str(tmp_path / "ray"), "--backend", "ray", "--workers", "2"])
    assert local.exit_code == 0 and remote.exit_code == 0, remote.output

    def rows(name):
        with (tmp_path / name / "metrics.csv").open() as handle:
            return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(handle)]

    assert rows("local") == rows("ray") and len(rows("ray")) == 4


# The tests below share two Ray workers, which hold both CPUs until the module ends: they come last.
POPSIZE, EPISODES = 101, 3  # an odd split: chunks of 51 and 50 candidates


@pytest.fixture(scope="module")
def backends():
    """The local backend and a two-worker Ray one on the same workload (Pendulum's episodes all last 200 steps)."""
    workload = Workload(make_policy("mlp:8", 3, 1), "Pendulum-v1", POPSIZE, EPISODES)
    local, remote = make_backend("local", workload), make_backend("ray", workload, workers=2)
    params = torch.randn(POPSIZE, workload.policy.num_params, generator=torch.Generator().manual_seed(0))
    yield local, remote, params, local.evaluate(params, seed=5)
    local.close()
    remote.close()


def same(a, b) -> bool:
    return (
        torch.equal(a.episode_returns, b.episode_returns)
        and torch.equal(a.terminated, b.terminated)
        and (a.steps, a.episodes) == (b.steps, b.episodes)
    )


@pytest.mark.slow
def test_ray_chunks_give_the_local_backend_s_numbers(backends):
    _local, remote, params, expected = backends
    assert remote.chunks == [(0, 51), (51, 101)]
    assert same(remote.evaluate(params, seed=5), expected)
    assert not same(remote.evaluate(params, seed=6), expected)


def test_a_killed_worker_s_chunk_runs_again_and_the_numbers_do_not_change(backends):
    _local, remote, params, expected = backends
    victim = remote.pids()[0]
    os.kill(victim, signal.SIGKILL)  # before its chunk is sent: a chunk of 0.1 s could outrun a timed kill
    deadline = time.perf_counter() + 10
    while alive(victim) and time.perf_counter() < deadline:
        time.sleep(0.01)
    with pytest.warns(UserWarning, match="a Ray worker died while evaluating candidates 0–50"):
        result = remote.evaluate(params, seed=5)
    assert remote.lost == 1 and same(result, expected)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_cluster_address_nothing_answers_at_is_refused_at_once():
    from drrl.rollout.ray import _check_reachable

    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"nothing answers at the Ray cluster address 127.0.0.1:1 .*ray start --head"):
        _check_reachable("127.0.0.1:1")
    assert time.perf_counter() - start < 10  # Ray's own retries take many minutes
    with pytest.raises(ValueError, match=r"--address 'somewhere' is not HOST:PORT"):
        _check_reachable("somewhere")
