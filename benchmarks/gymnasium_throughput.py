"""Policy-search throughput on third-party Gymnasium envs: drrl against EvoTorch, the same PGPE on both sides.

Env steps per second over whole generations: ask, every candidate's episode, tell. The same search on both sides:
symmetric PGPE, popsize 100 (``--popsize``), a linear policy with a bias starting at 0, σ₀ = 1, ClipUp on μ (step
0.1, momentum 0.9, max speed 0.2), σ learning rate 0.01 with its change bounded by 20 %, centred-rank fitness
shaping, one episode per candidate, no observation normalisation, one torch thread, one process (no Ray). Discrete
actions are the argmax of the policy's outputs, Box actions are clipped to their bounds, on both sides. Contenders:

* drrl, engine ``gymnasium``: Gymnasium's envs stepped in turn, an ended episode's env left alone;
* drrl, engine ``numba``: the same episodes compiled by Numba, in the caller's thread (classic control only);
* drrl, engine ``envpool``: EnvPool's C++ batch (a seeded reset makes the pool anew: once a generation);
* drrl, engine ``processes``: the gymnasium engine's envs spread over one worker process per core;
* EvoTorch ``GymNE``: one Gymnasium env, the candidates one after another;
* EvoTorch ``VecGymNE``: Gymnasium envs in EvoTorch's own vector env, the policy called on the whole batch.

Steps are the real env steps of the generation's episodes: ``Evaluation.steps`` for drrl, the generation's increase
of EvoTorch's ``total_interaction_count`` status. drrl's engines step no ended episode, so every sub-env step they
compute is counted. Each contender runs one warm-up generation, then one more that sets N, the same for all: enough
generations for 1.5 × ``--seconds`` of the fastest. Then ``--rounds`` rounds, each contender running N generations in
turn, the order alternating between rounds; N is raised after a round whose fastest contender took less. All contenders
thus stay at the same generation, where episode lengths are alike (they change as a search learns). Rates are
medians over rounds; ratios divide a row's median by GymNE's and VecGymNE's. Run on one core:

    taskset -c 1 python benchmarks/gymnasium_throughput.py
"""

from __future__ import annotations

import argparse
import logging
import math
import statistics
import time
import warnings

import torch
from evotorch.algorithms import PGPE
from evotorch.neuroevolution import GymNE, VecGymNE

from drrl.envs.batch import choose_engine
from drrl.settings import TrainConfig
from drrl.streams import Stream, derive_seed
from drrl.training.loop import run_generation
from drrl.training.train import prepare

SIGMA_INIT, CENTER_LR, SIGMA_LR, MAX_SIGMA_CHANGE = 1.0, 0.1, 0.01, 0.2


class Drrl:
    """drrl's own training pieces (``prepare``), one generation as ``ModelFree.step`` runs it (its backend, its
    seed), no measuring."""

    def __init__(self, env: str, engine: str, popsize: int):
        self.name = f"drrl ({engine})"
        config = TrainConfig(
            env=env,
            policy="linear",
            popsize=popsize,
            sampler="symmetric",
            optimizer="clipup",
            fitness_shaping="centered_ranks",
            sigma_init=SIGMA_INIT,
            center_lr=CENTER_LR,
            sigma_lr=SIGMA_LR,
            max_sigma_change=MAX_SIGMA_CHANGE,
            engine=engine,
            budget=10**9,
            eval_every=10**9,
            eval_episodes=1,
            observation_norm=False,
            reward_shift=0.0,  # the env's own returns, as EvoTorch's search is told (Hopper's default takes 1 a step)
        )  # as EvoTorch
        self.setup = prepare(config)
        self.generation = 0

    def step(self) -> int:
        self.generation += 1
        seed = derive_seed(self.setup.config.seed, self.generation, Stream.TRAINING)
        evaluation, _ = run_generation(self.setup.search, self.setup.world.backend, seed)
        return evaluation.steps

    def close(self) -> None:
        self.setup.close()


class EvoTorch:
    """EvoTorch's PGPE on ``GymNE`` or ``VecGymNE``, one ``searcher.step()`` a generation."""

    def __init__(self, env: str, kind: str, popsize: int):
        self.name = f"EvoTorch {kind}"
        problem_class = {"GymNE": GymNE, "VecGymNE": VecGymNE}[kind]
        self.problem = problem_class(
            env, "Linear(obs_length, act_length)", observation_normalization=False, num_episodes=1, num_actors=0
        )
        self.searcher = PGPE(
            self.problem,
            popsize=popsize,
            center_learning_rate=CENTER_LR,
            stdev_learning_rate=SIGMA_LR,
            stdev_init=SIGMA_INIT,
            stdev_max_change=MAX_SIGMA_CHANGE,
            optimizer="clipup",
            ranking_method="centered",
            symmetric=True,
            center_init=torch.zeros(self.problem.solution_length),
        )
        self.interactions = 0

    def step(self) -> int:
        self.searcher.step()
        total = int(self.searcher.status["total_interaction_count"])
        steps, self.interactions = total - self.interactions, total
        return steps

    def close(self) -> None:
        env = getattr(self.problem, "_env", None)
        if env is not None and hasattr(env, "close"):
            env.close()


def timed(contender, generations: int) -> tuple[float, int]:
    """Seconds and env steps of ``generations`` whole generations."""
    start, steps = time.perf_counter(), 0
    for _ in range(generations):
        steps += contender.step()
    return time.perf_counter() - start, steps


def can_run(env: str, engine: str) -> bool:
    """Whether drrl's ``engine`` can step ``env`` here (numba: classic control only; envpool: where installed)."""
    try:
        choose_engine(env, engine)
    except ValueError:
        return False
    return True


def measure(env: str, popsize: int, rounds: int, seconds: float, engines: list[str]) -> list[dict]:
    """All contenders run the same generations, so that their searches are at the same stage (episode lengths
    change as a search learns): N a round for all, aimed at 1.5 × ``seconds`` for the fastest contender and raised
    after a round whose fastest took less."""
    contenders = [
        *(Drrl(env, engine, popsize) for engine in engines if can_run(env, engine)),
        EvoTorch(env, "GymNE", popsize),
        EvoTorch(env, "VecGymNE", popsize),
    ]
    results = {contender.name: [] for contender in contenders}
    aim = 1.5 * seconds  # a margin: episodes shorten as a search learns, and a round with them
    try:
        for contender in contenders:
            timed(contender, 1)  # warm-up: envs made, first resets, lazily built pieces
        count = max(math.ceil(aim / timed(contender, 1)[0]) for contender in contenders)
        for r in range(rounds):
            for contender in contenders if r % 2 == 0 else contenders[::-1]:
                results[contender.name].append((count, *timed(contender, count)))
            fastest = min(results[contender.name][-1][1] for contender in contenders)
            count = max(count, math.ceil(count * aim / fastest))
    finally:
        for contender in contenders:
            contender.close()
    return [
        dict(
            env=env,
            contender=name,
            generations="/".join(str(n) for n, _, _ in runs),
            seconds=statistics.median(s for _, s, _ in runs),
            steps_per_generation=statistics.median(steps / n for n, _, steps in runs),
            rate=statistics.median(steps / s for _, s, steps in runs),
        )
        for name, runs in results.items()
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default="Acrobot-v1,Hopper-v5", help="comma-separated Gymnasium ids")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--popsize", type=int, default=100)
    parser.add_argument("--seconds", type=float, default=2.0, help="least time of one contender's round")
    parser.add_argument("--engines", default="gymnasium,numba,envpool", help="comma-separated drrl engines")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)  # EvoTorch's sampling
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    logging.getLogger("evotorch").setLevel(logging.WARNING)  # its INFO lines on every problem and optimizer made
    rows = [
        row
        for env in args.envs.split(",")
        for row in measure(env.strip(), args.popsize, args.rounds, args.seconds, args.engines.split(","))
    ]
    print(
        f"popsize {args.popsize}, linear policy with bias, 1 episode per candidate, {args.rounds} rounds, "
        f"torch threads {torch.get_num_threads()}\n"
    )
    print(
        "| env | contender | generations per round (N) | median s per round | median steps per generation "
        "| median env-steps/s | ÷ GymNE | ÷ VecGymNE |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        same_env = {other["contender"]: other["rate"] for other in rows if other["env"] == row["env"]}
        print(
            f"| {row['env']} | {row['contender']} | {row['generations']} | {row['seconds']:.2f} "
            f"| {row['steps_per_generation']:,.0f} | {row['rate']:,.0f} "
            f"| {row['rate'] / same_env['EvoTorch GymNE']:.2f} | {row['rate'] / same_env['EvoTorch VecGymNE']:.2f} |"
        )


if __name__ == "__main__":
    main()
