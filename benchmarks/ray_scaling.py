"""Ray backend against the local one on one CPU-bound generation: throughput with 1 and 2 workers, overhead.

One fixed population is evaluated again and again by three backends side by side in one run,
in rotating order: the local backend (this process), Ray with 1 worker and Ray with 2 workers. Ray is started with
3 logical CPUs so that both Ray backends' actors exist at once; only one backend works at a time. The driver runs
PyTorch on one thread, as Ray's one-CPU actors do, so that "local" and "Ray, 1 worker" do the same work on one core,
and Ray's workers run at the driver's niceness (Ray's default, 15, would hand their cores to any other process on
a shared machine; --worker-niceness 15 measures that).
Wall and CPU time (driver plus actors, from /proc) are reported as medians over the repeats; every evaluation is
checked bit-identical to the local backend's.

    drrl train cartpole --out runs/centre          # a balancing policy, so that every episode lasts 200 steps
    python benchmarks/ray_scaling.py --centre runs/centre --popsize 5000 --repeats 7

The population is drawn around that run's best centre with σ = --sigma (without --centre: PGPE's first ask, whose
random policies fail within a few dozen steps, so that the Python loop, not the env, dominates).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import ray
import torch

from drrl.envs.batch import make_batch_env
from drrl.rollout import Workload, make_backend
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.train import build_policy, build_search

TICKS = os.sysconf("SC_CLK_TCK")


def load_average() -> list[str]:
    """The 1, 5 and 15 minute load averages, as /proc/loadavg gives them."""
    with open("/proc/loadavg") as file:
        return file.read().split()[:3]


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of process ``pid`` so far."""
    with open(f"/proc/{pid}/stat") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def timed(backend, pids: list[int], params: torch.Tensor, seed: int):
    pids = [os.getpid(), *pids]
    cpu, wall = sum(map(cpu_seconds, pids)), time.perf_counter()
    result = backend.evaluate(params, seed)
    return result, time.perf_counter() - wall, sum(map(cpu_seconds, pids)) - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="cartpole")
    parser.add_argument("--policy", default="mlp:32,32")
    parser.add_argument("--popsize", type=int, default=2000)
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--max-steps", type=int)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--centre", help="run folder whose best centre the population is drawn around")
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--worker-niceness", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.centre:
        args.policy = RunFolder(args.centre).read_config().policy
    config = TrainConfig(
        env=args.env,
        policy=args.policy,
        popsize=args.popsize,
        episodes_per_candidate=args.episodes,
        budget=args.popsize * args.episodes,
        max_steps=args.max_steps,
    )
    probe = make_batch_env(args.env, 1)
    policy = build_policy(config, probe)
    env_id = probe.spec.id if probe.spec else args.env
    probe.close()
    params = build_search(config, policy).ask()
    if args.centre:
        centre = RunFolder(args.centre).load_checkpoint()["best_center"]
        noise = torch.randn(args.popsize, centre.numel(), generator=torch.Generator().manual_seed(0))
        params = centre + args.sigma * noise
    workload = Workload(policy, env_id, args.popsize, args.episodes, args.max_steps)
    ray.init(
        num_cpus=3,
        include_dashboard=False,
        log_to_driver=False,
        _system_config={"worker_niceness": args.worker_niceness},
    )
    backends = {
        "local": make_backend("local", workload),
        "ray, 1 worker": make_backend("ray", workload, workers=1),
        "ray, 2 workers": make_backend("ray", workload, workers=2),
    }
    pids = {
        "local": [],
        "ray, 1 worker": backends["ray, 1 worker"].pids(),
        "ray, 2 workers": backends["ray, 2 workers"].pids(),
    }
    names = list(backends)
    wall = {name: [] for name in names}
    cpu = {name: [] for name in names}
    steps = None
    print(
        f"{args.env}, {args.policy}, P = {args.popsize} × {args.episodes} episode(s), Ray workers at niceness "
        f"{args.worker_niceness}; load average before: {load_average()}"
    )
    for repeat in range(args.repeats + 1):  # the same generation each time; the first round warms up, not counted
        reference = None
        for name in names[repeat % 3 :] + names[: repeat % 3]:
            result, seconds, cpu_used = timed(backends[name], pids[name], params, seed=0)
            reference = reference or result
            assert torch.equal(result.episode_returns, reference.episode_returns), f"{name} differs"
            steps = result.steps
            if repeat:
                wall[name].append(seconds)
                cpu[name].append(cpu_used)
    for backend in backends.values():
        backend.close()
    ray.shutdown()
    median = {name: statistics.median(wall[name]) for name in names}
    print(f"load average after: {load_average()}; env-steps per generation: {steps}")
    for name in names:
        print(
            f"{name:15} {median[name]:7.3f} s/generation (range {min(wall[name]):.3f}–{max(wall[name]):.3f}), "
            f"{steps / median[name]:10,.0f} env-steps/s, CPU {statistics.median(cpu[name]):.3f} s"
        )
    print(f"2 workers / 1 worker throughput: {median['ray, 1 worker'] / median['ray, 2 workers']:.2f}×")
    print(f"Ray overhead, 1 worker against local: {median['ray, 1 worker'] / median['local'] - 1:+.1%}")
    print("all evaluations bit-identical to the local backend's")


if __name__ == "__main__":
    main()
