"""Real training episodes until the centre policy reaches Baxter's target (thesis 5.2, reward 5.10).

For each seed, drrl's training loop (``drrl.training.loop.run``, what ``drrl.training.train.train`` runs) spends
a budget of real episodes on PGPE over a Baxter reach env. Every ``--probe-every`` generations the centre policy μ runs
``--eval-episodes`` fresh episodes (counted apart, never as training), and we record the fraction that end with the
end-point(s) within 0.05 m of the target(s) and not failed. Prints, per seed, the real episodes and training wall time
when μ first reached ``--goal`` (95 % for a fixed target) and the final fraction; then medians over seeds.

    python benchmarks/baxter_reach.py --seeds 5
    python benchmarks/baxter_reach.py --env drrl/BaxterReachRightRandom-v0 --goal 0.8 --budget 4000
    python benchmarks/baxter_reach.py --env drrl/BaxterReachTargets-v0 --center-lr 0.1 \
        --schedule tolerance:0.5:0.05:1 --advance-at -1000 --budget 1500
    python benchmarks/baxter_reach.py --model-based '{"model_kind": "linear"}' --budget 30 --probe-every 1

With ``--model-based`` (JSON of ``ModelBasedSettings`` fields) the search runs inside a world model, a probe after
every iteration; ``--popsize`` then counts imagined candidates, each on 10 imagined episodes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time

import numpy as np
import torch

from drrl.envs.batch import ActionMap, make_batch_env
from drrl.envs.baxter.task import reach_fraction
from drrl.policies import Policy
from drrl.runs import RunFolder
from drrl.settings import EnvSchedule, TrainConfig
from drrl.training.loop import Counters, Setup, Subscriber, run
from drrl.training.train import build_policy, prepare, subscribers


@torch.inference_mode()
def final_distances(policy: Policy, center: torch.Tensor, env, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Run μ on every sub-env of ``env`` once: each episode's largest end-point distance at its last step, and
    whether it failed."""
    n = env.num_envs
    action_map, weights, state = ActionMap(env.single_action_space), policy.unflatten(center[None]), None
    state = policy.initial_state(1, n)
    obs, _ = env.reset(seed=[seed * 1_000_003 + i for i in range(n)])
    running, failed, distance = np.ones(n, dtype=bool), np.zeros(n, dtype=bool), np.full(n, np.nan)
    while running.any():
        raw, state = policy.act(weights, torch.as_tensor(obs).view(1, n, -1), state)
        obs, _, terminated, truncated, info = env.step(action_map(raw.reshape(n, -1)))
        ended = running & (terminated | truncated)
        distance[ended] = info["distance"][ended]
        failed |= running & terminated
        running &= ~ended
    return distance, failed


class GoalReached(Exception):
    """Raised by a probe told to stop the run once the centre reaches the goal."""


class ReachProbe(Subscriber):
    """A subscriber of the training loop that, at the start, at every checkpoint and at the end, measures how often
    the centre policy ends at its target; with ``stop_at`` a fraction, it stops the run once that is reached."""

    def __init__(self, config: TrainConfig, eval_episodes: int, verbose: bool = False, stop_at: float | None = None):
        self.seed, self.verbose, self.stop_at = config.seed, verbose, stop_at
        self.env = make_batch_env(config.env, eval_episodes)
        self.policy = build_policy(config, self.env)
        self.start = time.perf_counter()
        self.probing_seconds = 0.0  # not training time
        self.history: list[dict] = []  # one row per probe

    def started(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        self.start = time.perf_counter()
        self.probe(snapshot)

    def checkpoint(self, snapshot: dict) -> None:
        self.probe(snapshot)

    def ended(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        self.probe(snapshot)

    def probe(self, state: dict) -> None:
        if self.history and self.history[-1]["generation"] == state["iteration"]:
            return  # the final checkpoint repeats the last one
        probe_start = time.perf_counter()
        distance, failed = final_distances(self.policy, state["center"], self.env, seed=state["iteration"])
        self.history.append(
            {
                "generation": state["iteration"],
                "real_episodes": state["real_episodes"],
                "seconds": probe_start - self.start - self.probing_seconds,
                "reached": reach_fraction(torch.as_tensor(distance), torch.as_tensor(failed)),
                "failed": float(failed.mean()),
                "median_distance": float(np.median(distance)),
            }
        )
        self.probing_seconds += time.perf_counter() - probe_start
        if self.verbose:
            row = self.history[-1]
            print(
                f"  seed {self.seed} generation {row['generation']}: {row['real_episodes']} episodes, "
                f"{row['seconds']:.0f} s, reached {row['reached']:.2f}, failed {row['failed']:.2f}, "
                f"median distance {row['median_distance']:.3f} m",
                flush=True,
            )
        if self.stop_at is not None and self.history[-1]["reached"] >= self.stop_at:
            raise GoalReached


def run_seed(args, seed: int) -> list[dict]:
    config = TrainConfig(
        env=args.env,
        policy=args.policy,
        sampler="symmetric",
        optimizer=args.optimizer,
        fitness_shaping="centered_ranks",
        popsize=args.popsize,
        budget=args.budget,
        sigma_init=args.sigma_init,
        center_lr=args.center_lr,
        sigma_lr=args.sigma_lr,
        eval_episodes=1,
        eval_every=10**6,
        checkpoint_every=args.probe_every,
        seed=seed,
        env_schedule=schedule(args.schedule, args.advance_at, args.steps),
        model_based=json.loads(args.model_based) if args.model_based else None,
    )
    with tempfile.TemporaryDirectory() as folder:
        probe = ReachProbe(config, args.eval_episodes, args.verbose, args.goal if args.stop_at_goal else None)
        try:  # drrl.training.train.train's loop and run folder, with the probe told of every checkpoint
            run(prepare(config), [*subscribers(RunFolder(folder), progress=False), probe])
        except GoalReached:
            pass
        finally:
            probe.env.close()
    return probe.history


def schedule(text: str | None, advance_at: float | None, steps: int) -> EnvSchedule | None:
    """``OPTION:START:END:SHARE`` (e.g. tolerance:0.5:0.05:0.5) as an env schedule; by its steps if ``advance_at``."""
    if text is None:
        return None
    option, start, end, share = text.split(":")
    return EnvSchedule(
        option=option, start=float(start), end=float(end), share=float(share), advance_at=advance_at, steps=steps
    )


def first(history: list[dict], goal: float) -> dict | None:
    return next((row for row in history if row["reached"] >= goal), None)


def median_or_miss(values: list[float | None]) -> str:
    median = statistics.median(float("inf") if v is None else v for v in values)
    return "not reached" if median == float("inf") else f"{median:.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="drrl/BaxterReachRight-v0")
    parser.add_argument("--policy", default="linear")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0, help="run seeds first-seed, first-seed + 1, ...")
    parser.add_argument("--budget", type=int, default=800, help="real training episodes per seed")
    parser.add_argument("--popsize", type=int, default=20)
    parser.add_argument("--optimizer", default="clipup")
    parser.add_argument("--sigma-init", type=float, default=0.05)
    parser.add_argument("--center-lr", type=float, default=0.15)
    parser.add_argument("--sigma-lr", type=float, default=0.05)
    parser.add_argument("--probe-every", type=int, default=5, help="generations between measurements of μ")
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--schedule", help="a curriculum on an env option, OPTION:START:END:SHARE of the budget")
    parser.add_argument("--advance-at", type=float, help="the schedule steps when the median return reaches this")
    parser.add_argument("--steps", type=int, default=10, help="the schedule's steps, with --advance-at")
    parser.add_argument("--goal", type=float, default=0.95, help="fraction of episodes that must end at the target")
    parser.add_argument("--model-based", help="JSON of ModelBasedSettings fields: search in a world model")
    parser.add_argument("--stop-at-goal", action="store_true", help="end a seed's run once μ reaches the goal")
    parser.add_argument("--verbose", action="store_true", help="print every measurement of μ")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(
        f"{args.env}, {args.policy} policy, popsize {args.popsize}, {args.optimizer} lr {args.center_lr}, "
        f"σ₀ {args.sigma_init}, budget {args.budget}, μ measured on {args.eval_episodes} episodes every "
        f"{args.probe_every} generations"
        + (f", schedule {schedule(args.schedule, args.advance_at, args.steps)}" if args.schedule else "")
    )
    print("| seed | episodes to goal | seconds to goal | final reached | final failed | final median distance (m) |")
    print("| --- | --- | --- | --- | --- | --- |")
    episodes, seconds = [], []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        history = run_seed(args, seed)
        hit, last = first(history, args.goal), history[-1]
        episodes.append(hit["real_episodes"] if hit else None)
        seconds.append(hit["seconds"] if hit else None)
        reached = f"{hit['real_episodes']} | {hit['seconds']:.0f}" if hit else "not reached | -"
        print(
            f"| {seed} | {reached} | {last['reached']:.2f} | {last['failed']:.2f} | {last['median_distance']:.3f} |",
            flush=True,
        )
    hits = sum(e is not None for e in episodes)
    print(
        f"\nmedian real episodes to {args.goal:.0%}: {median_or_miss(episodes)}; median seconds: "
        f"{median_or_miss(seconds)}; seeds reaching the goal: {hits}/{args.seeds}"
    )


if __name__ == "__main__":
    main()
