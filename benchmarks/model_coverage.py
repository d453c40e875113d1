"""Can a world model fitted on a few real episodes tell a good policy from a bad one? Fitted on episodes around one
policy, measured on another's.

A run folder gives a trained policy μ* (its best measured centre). The env's model-based world model (its
model-based defaults, or ``--model-based``) is fitted on real episodes of a base policy and of ``--pairs`` pairs
base ± ε (σ = ``--sigma``): the base is μ = 0, as a model-based run's first iteration explores (``--around zero``),
or μ* itself (``--around trained``). Then, on three fresh real episodes of μ*, the model's k-step error (units of
each entry's per-step change, median over starts; ``drrl.models.quality.k_step_errors``), and the returns the model
imagines for μ* and for μ = 0 beside their real ones. A model-based search can only find μ* if the model ranks it
above μ = 0.

    python benchmarks/model_coverage.py runs/reach --around zero
    python benchmarks/model_coverage.py runs/reach --around trained
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from drrl.envs.batch import RegisteredEnv, make_batch_env
from drrl.envs.registry import lookup
from drrl.models import EpisodeBuffer
from drrl.models.imagined import ImaginedEnv, TaskKnowledge
from drrl.models.kinds import fit_model
from drrl.models.quality import k_step_errors
from drrl.models.trainer import fitting_settings
from drrl.rollout import evaluate
from drrl.runs import RunFolder
from drrl.settings import TrainConfig
from drrl.training.model_based import build_model, collect, episode_horizon
from drrl.training.train import build_policy, open_run

HORIZONS = (1, 10, 50, 100, 300)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a run folder whose best measured centre is μ*")
    parser.add_argument("--around", choices=("zero", "trained"), default="zero")
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--sigma", type=float, default=0.05)
    parser.add_argument("--model-based", default="{}", help="JSON of ModelBasedSettings fields to change")
    parser.add_argument("--imagined-horizon", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    trained, checkpoint = open_run(RunFolder(args.run))
    entry = lookup(checkpoint["env_id"])
    config = TrainConfig.model_validate({"env": trained.env, "model_based": json.loads(args.model_based)})
    env = make_batch_env(entry.env_id, 10)
    policy = build_policy(trained, env)
    best = checkpoint["best_center"]
    base = best if args.around == "trained" else torch.zeros_like(best)
    noise = args.sigma * torch.randn(args.pairs, best.numel(), generator=torch.Generator().manual_seed(args.seed))
    source = RegisteredEnv(entry.env_id, trained.engine)
    episodes, _ = collect(policy, torch.cat([base[None], base + noise, base - noise]), source, args.seed, None)
    buffer = EpisodeBuffer(episodes)
    print(
        f"{entry.env_id}: fitted on {len(buffer)} real episodes around μ = {args.around} (σ {args.sigma}), "
        f"lengths {[len(e) for e in episodes]}, returns {[round(float(e.rewards.sum())) for e in episodes]}"
    )
    settings = config.model_based
    assert settings is not None
    model = build_model(settings, env.single_observation_space.shape[0], env.single_action_space, args.seed)
    fitting = fitting_settings(settings.fit_settings(True, entry.reward is None), buffer)
    fit_model(model, buffer, fitting, seed=args.seed)
    judged, _ = collect(policy, torch.stack([best] * 3), source, args.seed + 1, None)
    errors = k_step_errors(model, EpisodeBuffer(judged), max(HORIZONS))
    print("k-step error on μ*'s real episodes: " + ", ".join(f"k = {k}: {errors[k - 1]:.2f}" for k in HORIZONS))
    for name, center in (("μ*", best), ("μ = 0", torch.zeros_like(best))):
        real = float(evaluate(policy, center[None], env, 10, seed=args.seed + 2).returns[0])
        imagined = []
        for horizon in (args.imagined_horizon, episode_horizon(entry.env_id, env)):
            world = ImaginedEnv(
                model,
                buffer.start_observations(),
                10,
                env.single_action_space,
                horizon,
                TaskKnowledge(entry.reward, complete_observation=entry.complete_observation),
            )
            imagined.append(float(evaluate(policy, center[None], world, 10, seed=args.seed + 3).returns[0]))
        print(f"{name}: real return {real:.0f}; imagined over {args.imagined_horizon} / all steps {np.round(imagined)}")


if __name__ == "__main__":
    main()
