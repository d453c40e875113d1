"""Throughput of the batched Baxter env under a linear policy against MuJoCo stepping the same model alone.

Side by side, on the same cores and threads, from the same start states, interleaved and repeated (medians):

- env + policy: ``drrl.rollout.evaluate`` of N linear candidates for S control steps, each a policy call, an
  ``env.step`` (5 physics steps in C threads, then reward and observation in NumPy);
- raw mj_step: the env's own MuJoCo batch (N MjData, same threads) asked for all N·5·S physics steps in one call,
  with no Python between them: the rate MuJoCo itself reaches for this model here;
- raw mj_step a control period a call: the same batch asked for 5 physics steps S times, as the env asks it (with
  the env's stages computed after each call), with nothing else between the calls. What it loses against one call
  is MuJoCo's cost of stepping closed-loop (each call visits every simulation's data again, and waits for its
  threads); what the env loses against it is drrl's own work, and what that work's pause costs MuJoCo's threads;
- raw mj_step a control period a call with a pause: the same, with ``--pause-us`` microseconds of busy waiting
  between calls, about as long as drrl's own work a step: what a pause between calls costs MuJoCo itself (its
  thread pool's threads go idle and must be woken).

Both count physics steps per second: the median over repeats and, in brackets, the best, which on a shared machine
is the closer estimate of what the code can do. Physics steps per process CPU-second are reported too. Restrict
the cores with taskset; threads default to the cores allowed:

    taskset -c 0,1 python benchmarks/baxter_throughput.py
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from drrl.envs.batch import make_batch_env
from drrl.policies import linear
from drrl.rollout import evaluate


def timed(work) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of ``work()``."""
    wall, cpu = time.perf_counter(), time.process_time()
    work()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="drrl/BaxterReachRight-v0")
    parser.add_argument("--num-envs", type=int, default=100)
    parser.add_argument("--steps", type=int, default=200, help="control steps per measurement")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--pause-us", type=float, default=500.0, help="busy pause between calls of the last row")
    args = parser.parse_args()
    torch.set_num_threads(1)  # the physics gets the cores

    env = make_batch_env(args.env, args.num_envs)
    sims = env.robot  # the same MuJoCo batch the env steps
    obs_size, act_size = env.single_observation_space.shape[0], env.single_action_space.shape[0]
    policy = linear(obs_size, act_size)
    # small random weights: the arms move slowly and nothing fails within S steps
    candidates = 0.02 * torch.randn(args.num_envs, policy.num_params, generator=torch.Generator().manual_seed(0))
    physics_steps = args.num_envs * args.steps * sims.substeps

    def with_policy() -> None:
        evaluate(policy, candidates, env, episodes=1, seed=0, max_steps=args.steps)

    def raw() -> None:
        sims.batch.step(nstep=args.steps * sims.substeps)

    def raw_per_period() -> None:
        for _ in range(args.steps):
            sims.batch.step(nstep=sims.substeps, stage=sims.stage)

    def raw_per_period_paused() -> None:
        for _ in range(args.steps):
            pause_until = time.perf_counter() + args.pause_us * 1e-6
            while time.perf_counter() < pause_until:
                pass
            sims.batch.step(nstep=sims.substeps, stage=sims.stage)

    env_times, raw_times, period_times, paused_times = [], [], [], []
    for _ in range(args.repeats):
        env_times.append(timed(with_policy))
        env.reset(seed=0)  # the same start states, at rest
        raw_times.append(timed(raw))
        env.reset(seed=0)
        period_times.append(timed(raw_per_period))
        env.reset(seed=0)
        paused_times.append(timed(raw_per_period_paused))
    pause = args.steps * args.pause_us * 1e-6  # not MuJoCo's time: taken off the paused row's wall and CPU times
    paused_times = [(wall - pause, cpu - pause) for wall, cpu in paused_times]
    print(
        f"{args.env}: {args.num_envs} envs × {args.steps} control steps × {sims.substeps} physics steps, "
        f"{sims.batch.nthread} MuJoCo threads, {args.repeats} interleaved repeats"
    )
    print("| | physics steps/s, median (best) | physics steps per CPU-second, median |")
    print("| --- | --- | --- |")
    rows = (
        ("batched env + linear policy", env_times),
        ("raw mj_step, same batch", raw_times),
        ("raw mj_step, a control period a call", period_times),
        (f"raw mj_step, a control period a call, {args.pause_us:.0f} µs pauses (not counted)", paused_times),
    )
    for name, times in rows:
        walls, cpus = [wall for wall, _ in times], [cpu for _, cpu in times]
        print(
            f"| {name} | {physics_steps / statistics.median(walls):,.0f} ({physics_steps / min(walls):,.0f}) | "
            f"{physics_steps / statistics.median(cpus):,.0f} |"
        )
    ratios = (
        ("env / raw", raw_times),
        ("env / raw a control period a call", period_times),
        ("env / raw a control period a call with pauses", paused_times),
    )
    for name, times in ratios:
        wall, best, cpu = ratio(times, env_times, 0), ratio(times, env_times, 0, min), ratio(times, env_times, 1)
        print(f"| {name} | {wall} ({best}) | {cpu} |")


def ratio(fast: list[tuple[float, float]], slow: list[tuple[float, float]], which: int, pick=statistics.median) -> str:
    """How fast ``slow`` runs beside ``fast``, from the picked wall (which=0) or CPU (1) times."""
    return f"{pick(t[which] for t in fast) / pick(t[which] for t in slow):.0%}"


if __name__ == "__main__":
    main()
