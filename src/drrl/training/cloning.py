"""A run's first centre cloned from demonstrations: behaviour cloning (beyond the thesis).

Where an env has a scripted demonstrator (``EnvEntry.demonstrator``, e.g. the stacking tasks' scripted stacker),
``cloned`` records real episodes, counted as training episodes, in which the demonstrator's action is noted at every
step, and ``clone`` fits the policy's weights to those actions by least squares; the search then starts from those
weights instead of from nothing. A copy's small errors take it where no clean demonstration went, so

- the episodes are recorded in rounds, as DAgger does (Ross et al. 2011): the first driven by the demonstrator, each
  later one by the clone of all episodes before it, whose mistakes the demonstrator's actions then correct;
- as DART does (Laskey et al. 2017), Gaussian noise is added to the actions the env is given (not to those noted).

Fitting follows the world model's (``drrl.models.fit``): Adam on minibatches, the inputs standardised and the
standardisation folded into the first layer afterwards (``Policy.fold_input``), so the policy reads raw observations.

Only feed-forward policies are cloned: a demonstrator without memory is a function of the observation, which they
are too (a recurrent policy would be fitted through time).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from drrl.envs.batch import ActionMap, make_batch_env
from drrl.envs.registry import Demonstrator
from drrl.policies import Policy
from drrl.policies.feedforward import FeedForward

Actor = Callable[[np.ndarray], np.ndarray]  # observations (N, o) -> raw outputs (N, a)

BATCH = 2048  # steps a minibatch
UPDATES = 3000  # Adam steps a fit
LEARNING_RATE = 1e-2


@dataclass(frozen=True)
class Demonstrations:
    """Every step of some real episodes of a demonstrator: what it observed and the raw policy outputs (before
    ``ActionMap``) that give its actions, and what the episodes spent."""

    observations: np.ndarray  # (steps, o) float32
    raw_actions: np.ndarray  # (steps, a) float32
    episodes: int

    @property
    def steps(self) -> int:
        return len(self.observations)


def demonstrated(
    demonstrator: Demonstrator,
    env_id: str,
    episodes: int,
    seed: int,
    noise: float,
    engine: str = "auto",
    max_steps: int | None = None,
    actor: Actor | None = None,
    stepped: Callable[[int, int], None] | None = None,
) -> Demonstrations:
    """``episodes`` real episodes on ``env_id`` in one batch, seeded by ``seed``, with the raw outputs that give
    ``demonstrator``'s action at every step; the env is given ``actor``'s raw outputs (observations → raw outputs,
    e.g. a clone's, as DAgger does; the demonstrator's own if None) plus N(0, ``noise``²) on each (a bounded Box's
    outputs span [−1, 1]). ``stepped(steps, ended)`` is told after every step of the batch."""
    env = make_batch_env(env_id, episodes, engine)
    action_map, rng = ActionMap(env.single_action_space), np.random.default_rng(seed)
    observed, actions = [], []
    running = np.ones(episodes, dtype=bool)
    steps, horizon = 0, max_steps if max_steps is not None else 10**9
    try:
        observations, _ = env.reset(seed=seed)
        while running.any() and steps < horizon:
            raw = action_map.raw(demonstrator(observations))
            observed.append(observations[running])
            actions.append(raw[running])
            acted = raw if actor is None else actor(observations)
            noisy = acted + noise * rng.standard_normal(raw.shape).astype(np.float32)
            observations, _, terminated, truncated, _ = env.step(action_map(torch.from_numpy(noisy)))
            steps += 1
            running &= ~(terminated | truncated)
            if stepped is not None:
                stepped(steps, episodes - int(running.sum()))
    finally:
        env.close()
    return Demonstrations(np.concatenate(observed).astype(np.float32), np.concatenate(actions), episodes)


def check_clonable(policy: Policy, demonstrator: Demonstrator | None, env_id: str) -> None:
    """Refuse, in one line, an env without a demonstrator or a policy that is not feed-forward."""
    if demonstrator is None:
        raise ValueError(
            f"demonstrations: {env_id} has no scripted demonstrator (the stacking tasks with end-point "
            "actions have one)"
        )
    if not isinstance(policy, FeedForward):
        raise ValueError(
            "demonstrations are cloned into feed-forward policies (linear, multilinear, mlp); "
            f"this run's policy is {type(policy).__name__}"
        )


def clone(policy: Policy, demonstrations: Demonstrations, seed: int, device: str = "cpu") -> torch.Tensor:
    """The weights (n,) whose policy's raw outputs are closest, in squared error, to the demonstrations', reading raw
    observations: from ``policy.initial_center``, UPDATES Adam steps on minibatches of BATCH steps, the step size
    falling linearly."""
    generator = torch.Generator().manual_seed(seed)
    inputs = torch.as_tensor(demonstrations.observations, device=device)
    targets = torch.as_tensor(demonstrations.raw_actions, device=device)
    mean = inputs.mean(0) if policy.input_bias else torch.zeros_like(inputs[0])  # only a bias takes the shift
    std = inputs.std(0).clamp_min(1e-3)
    inputs = (inputs - mean) / std
    params = policy.initial_center(generator).to(device)[None].requires_grad_(True)
    optimizer = torch.optim.Adam([params], lr=LEARNING_RATE)
    schedule = torch.optim.lr_scheduler.LinearLR(optimizer, 1.0, 0.01, UPDATES)  # to a hundredth, for a precise end
    batches = torch.randperm(len(inputs), generator=generator).split(BATCH)
    for update in range(UPDATES):
        if update and update % len(batches) == 0:  # a new pass over the demonstrations, in a new order
            batches = torch.randperm(len(inputs), generator=generator).split(BATCH)
        rows = batches[update % len(batches)].to(device)
        outputs, _ = policy.act(policy.unflatten(params), inputs[rows][None], None)
        loss = torch.mean((outputs[0] - targets[rows]) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    return policy.fold_input(params.detach(), mean, std)[0].cpu()


def cloned(
    policy: Policy,
    demonstrator: Demonstrator,
    env_id: str,
    episodes: int,
    rounds: int,
    seed: int,
    noise: float,
    engine: str = "auto",
    max_steps: int | None = None,
    device: str = "cpu",
    progress: bool = False,
) -> tuple[torch.Tensor, Demonstrations]:
    """The clone (n,) after ``rounds`` rounds of ``episodes`` real episodes in all (``demonstrated``; the first
    round driven by the demonstrator, each later one by the clone so far), and every episode recorded; with
    ``progress``, a bar of the episodes recorded, the round's step and what it is doing."""
    center: torch.Tensor | None = None
    recorded: list[Demonstrations] = []
    bar = tqdm(total=episodes, unit="ep", desc="demonstrations", disable=not progress, dynamic_ncols=True)
    for round_ in range(rounds):
        share = episodes * (round_ + 1) // rounds - episodes * round_ // rounds
        actor = None if center is None else acting(policy, center)
        here = int(np.random.SeedSequence([seed, round_]).generate_state(1)[0])
        named = f"round {round_ + 1} of {rounds}: " if rounds > 1 else ""
        stepped = _recording(bar, f"{named}step {{}} of the {share} episodes")
        recorded.append(demonstrated(demonstrator, env_id, share, here, noise, engine, max_steps, actor, stepped))
        record = joined(recorded)
        bar.set_postfix_str(f"{named}fitting the clone to {record.episodes} episodes")
        center = clone(policy, record, here, device)
    bar.close()
    assert center is not None
    return center, record


def _recording(bar: tqdm, label: str) -> Callable[[int, int], None]:
    """What a batch of demonstrations tells ``bar`` after each step: the episodes ended so far, ``label`` with the
    step."""
    before = bar.n

    def stepped(steps: int, ended: int) -> None:
        bar.set_postfix_str(label.format(steps), refresh=False)
        if before + ended > bar.n:
            bar.update(before + ended - bar.n)
        elif steps % 25 == 0:
            bar.refresh()

    return stepped


def acting(policy: Policy, center: torch.Tensor) -> Actor:
    """The raw outputs of the policy with weights ``center`` (n,), for observations on the CPU."""
    weights = policy.unflatten(center[None])

    def act(observations: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return policy.act(weights, torch.as_tensor(observations)[None], None)[0][0].numpy()

    return act


def joined(parts: list[Demonstrations]) -> Demonstrations:
    """The episodes of ``parts`` as one record."""
    return Demonstrations(
        np.concatenate([part.observations for part in parts]),
        np.concatenate([part.raw_actions for part in parts]),
        sum(part.episodes for part in parts),
    )
