"""World-model variants fitted on one run's real episodes, judged by their k-step error on another run's.

The held-out episodes come from a different seed's policies, so the error measures what imagination needs: the
model predicting, from a real start, many steps ahead in states its own data did not hold. Both run folders are
model-based runs (their checkpoints hold the real episodes), e.g. of the swing-up:

    drrl train cartpole-swingup --model-based --budget 16 --seed 1 --out runs/swingup-1
    drrl train cartpole-swingup --model-based --budget 16 --seed 2 --out runs/swingup-2
    python benchmarks/world_models.py runs/swingup-1 runs/swingup-2
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from drrl.models import EpisodeBuffer, FitSettings, WorldModel
from drrl.models.fit import fit
from drrl.models.quality import k_step_errors
from drrl.runs import RunFolder

VARIANTS = {
    "rnn 64": {"model_kind": "rnn", "hidden": [64]},
    "lstm 64": {"model_kind": "lstm", "hidden": [64]},
    "lstm 32": {"model_kind": "lstm", "hidden": [32]},
}
HORIZONS = (1, 5, 10, 25, 50)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("training", help="run folder whose real episodes the models are fitted on")
    parser.add_argument("held_out", help="run folder whose real episodes measure them")
    parser.add_argument(
        "--variants",
        default=json.dumps(VARIANTS),
        help="JSON: name → model_kind, hidden, members and any FitSettings fields",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    training, held_out = (
        EpisodeBuffer.from_state_dict(RunFolder(path).load_checkpoint()["world"]["buffer"])
        for path in (args.training, args.held_out)
    )
    print(
        f"{len(training)} training episodes ({training.num_steps} steps), {len(held_out)} held-out "
        f"({held_out.num_steps} steps)\n"
    )
    print(f"| model | fit s | {' | '.join(f'error at k = {k}' for k in HORIZONS)} |")
    print("| --- " * (len(HORIZONS) + 2) + "|")
    observation_size = training.episodes[0].observations.shape[1]
    action_size = training.episodes[0].actions.shape[1]
    for name, variant in json.loads(args.variants).items():
        variant = dict(variant)
        torch.manual_seed(args.seed)
        model = WorldModel(
            observation_size,
            action_size,
            variant.pop("hidden", [64]),
            variant.pop("model_kind", "rnn"),
            members=variant.pop("members", 5),
        )
        settings = FitSettings(**{"learn_reward": False, "batch_size": 128, "max_updates": 1000, **variant})
        start = time.perf_counter()
        fit(model, training, settings, seed=args.seed)
        seconds = time.perf_counter() - start
        errors = k_step_errors(model, held_out, max(HORIZONS))
        print(f"| {name} | {seconds:.0f} | {' | '.join(f'{errors[k - 1]:.2f}' for k in HORIZONS)} |", flush=True)


if __name__ == "__main__":
    main()
