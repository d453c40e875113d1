"""The cart-pole through the camera (drrl.envs.pixels): how fast frames are drawn, and what a run's world model
imagines from them.

``--throughput``: frames a second of the pixel env against steps a second of the state env, batches of 1 and 100
(median of ``--repeats`` rounds, the two envs alternating); then the same for Gymnasium's envs seen through their
own cameras (``Pixels/ID``, drrl.envs.rendered; ``--envs``), one env stepped with random actions against ``ID``
itself. ``--figure RUN``: real frames beside the model's imagined
frames over ``--steps`` steps from the same start, with the same actions: a real episode of the run's best centre
policy, then the run's world model (its first member) fed the encoded first frame and those actions, its own
predictions fed back (dynamical consistency), each predicted latent drawn by the run's autoencoder. ``--codes``:
how well the frame autoencoder's features tell the cart-pole's state: the autoencoder fitted (its first fit's
defaults) to the frames of 40 episodes of random linear state feedback, then an affine read-out of (s, ṡ, θ, θ̇) off
the features fitted on those frames and scored (R²) on the frames of 40 fresh episodes, for ``--seeds`` seeds.

    python benchmarks/pixels.py --throughput --envs Pendulum-v1,InvertedPendulum-v5
    python benchmarks/pixels.py --codes --seeds 3
    python benchmarks/model_based.py --env cartpole-pixels --seeds 5      # episodes to balanced from frames
    drrl train cartpole-pixels --model-based --out runs/pixels
    python benchmarks/pixels.py --figure runs/pixels --out docs/images/cartpole_pixels_imagined.png
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import gymnasium
import numpy as np
import torch

import drrl.envs  # noqa: F401  (registers the envs)
from drrl.envs.batch import make_batch_env
from drrl.envs.registry import lookup
from drrl.models.data import EpisodeRecorder
from drrl.models.frames import Encoding, fit_autoencoder
from drrl.rollout import evaluate
from drrl.runs import RunFolder
from drrl.settings import ModelBasedSettings
from drrl.training.model_based import ModelBased, frame_autoencoder
from drrl.training.train import open_run, prepare


def steps_per_second(env_id: str, num_envs: int, steps: int = 200) -> float:
    env = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-0.2, 0.2, (steps, num_envs, 1))
    start = time.perf_counter()
    for action in actions:
        env.step(action)
    return steps * num_envs / (time.perf_counter() - start)


def single_steps_per_second(env_id: str, steps: int = 300) -> float:
    """One env of ``env_id`` (any id drrl knows, ``Pixels/ID`` too) stepped with random actions, restarted at ends."""
    env = gymnasium.make(lookup(env_id).env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    seconds = time.perf_counter() - start
    env.close()
    return steps / seconds


def throughput(repeats: int, envs: list[str]) -> None:
    print("| batch | pixel env, frames/s | state env, steps/s | ratio |")
    print("| --- | --- | --- | --- |")
    for num_envs in (1, 100):
        rounds = [
            (steps_per_second("drrl/CartPolePixels-v0", num_envs), steps_per_second("drrl/CartPole-v0", num_envs))
            for _ in range(repeats)
        ]
        pixels, states = (statistics.median(column) for column in zip(*rounds, strict=True))
        print(f"| {num_envs} | {pixels:,.0f} | {states:,.0f} | {pixels / states:.3f} |")
    print("\n| env | Pixels/env, frames/s | env, steps/s | ratio |")
    print("| --- | --- | --- | --- |")
    for env_id in envs:
        rounds = [
            (single_steps_per_second(f"Pixels/{env_id}"), single_steps_per_second(env_id)) for _ in range(repeats)
        ]
        pixels, states = (statistics.median(column) for column in zip(*rounds, strict=True))
        print(f"| {env_id} | {pixels:,.0f} | {states:,.0f} | {pixels / states:.3f} |")


@torch.inference_mode()
def figure(run: Path, out: Path, steps: int, seed: int) -> None:
    config, checkpoint = open_run(RunFolder(run))
    setup = prepare(config)
    world = setup.world
    assert isinstance(world, ModelBased) and world.autoencoder is not None, f"{run} is not a model-based run on frames"
    world.load_state_dict(checkpoint["world"])
    recorder = EpisodeRecorder(make_batch_env(setup.entry.env_id, 1))
    evaluate(setup.policy, checkpoint["best_center"][None], Encoding(recorder, world.autoencoder), 1, seed, steps)
    setup.close()
    episode = recorder.episodes()[0]
    latent = torch.as_tensor(world.autoencoder.encode(episode.observations[:1]))
    state, imagined = world.model.initial_state(1), []
    for t, action in enumerate(torch.as_tensor(episode.actions)):
        prediction, state = world.model.step(latent, action[None], state, t == 0)
        latent = prediction.observations[0]
        imagined.append(latent[0].numpy())
    dreamt = world.autoencoder.draw(np.stack(imagined))
    plot(episode.observations[1:], dreamt, out, title=f"{setup.entry.env_id}: real (top) and imagined (bottom)")


def codes(seeds: int) -> None:
    settings = ModelBasedSettings()
    print("| seed | frames fitted | fresh frames | R² s | R² ṡ | R² θ | R² θ̇ | fit s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for seed in range(seeds):
        frames, states = random_feedback_frames(40, 2 * seed)
        fresh_frames, fresh_states = random_feedback_frames(40, 2 * seed + 1)
        autoencoder = frame_autoencoder(frames.shape[1:], settings, seed)
        start = time.perf_counter()
        features = fit_autoencoder(autoencoder, frames, settings.frame_updates, seed=seed).features
        seconds = time.perf_counter() - start
        inputs, fresh = (np.c_[x, np.ones(len(x))] for x in (features, autoencoder.encode(fresh_frames)))
        read_out = np.linalg.lstsq(inputs, states, rcond=None)[0]
        residual = ((fresh @ read_out - fresh_states) ** 2).sum(0)
        r2 = " | ".join(f"{v:.3f}" for v in 1 - residual / ((fresh_states - fresh_states.mean(0)) ** 2).sum(0))
        print(f"| {seed} | {len(frames)} | {len(fresh_frames)} | {r2} | {seconds:.0f} |")


def random_feedback_frames(episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The observations and true states of ``episodes`` episodes of the pixel cart-pole, each under a random linear
    feedback of the state (gains ~ N(0, 1)) plus noise (σ 0.5): the falling and swaying of a run's first episodes."""
    env, rng = gymnasium.make("drrl/CartPolePixels-v0"), np.random.default_rng(seed)
    observations, states = [], []
    for episode in range(episodes):
        observation, _ = env.reset(seed=1000 * seed + episode)
        gains, done = rng.normal(0, 1, 4), False
        while not done:
            state = np.array(env.unwrapped.state, dtype=np.float64).reshape(-1)  # a copy: the env steps in place
            observations.append(observation)
            states.append(state)
            action = np.clip([gains @ state + rng.normal(0, 0.5)], -1, 1).astype(np.float32)
            observation, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    return np.array(observations), np.array(states)


def plot(real: np.ndarray, imagined: np.ndarray, out: Path, title: str, columns: int = 10) -> None:
    """Every few steps' newest frame, real above imagined; the middle of each frame (rows 12–44, columns 8–56 of
    64: 4.5 m of track and the pole's reach), where the cart and pole are."""
    import matplotlib.pyplot as plt

    shown = np.linspace(0, len(real) - 1, min(columns, len(real))).round().astype(int)
    fig, axes = plt.subplots(2, len(shown), figsize=(1.5 * len(shown), 2.6), squeeze=False)
    for column, t in enumerate(shown):
        for row, frames in enumerate((real, imagined)):
            axes[row, column].imshow(frames[t, -1, 12:44, 8:56], cmap="gray", vmin=0, vmax=255)
            axes[row, column].set_xticks([])
            axes[row, column].set_yticks([])
        axes[1, column].set_xlabel(f"step {t + 1}")
    axes[0, 0].set_ylabel("real")
    axes[1, 0].set_ylabel("imagined")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(f"wrote {out}: {len(real)} steps, frames {', '.join(str(t + 1) for t in shown)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--throughput", action="store_true")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--envs", default="", help="Gymnasium ids to see through their cameras, comma-separated")
    parser.add_argument("--figure", type=Path, help="a model-based run folder on frames")
    parser.add_argument("--out", type=Path, default=Path("imagined_frames.png"))
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--codes", action="store_true")
    parser.add_argument("--seeds", type=int, default=3, help="--codes: autoencoders fitted, each to its own data")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.throughput:
        throughput(args.repeats, [env for env in args.envs.split(",") if env])
    if args.figure:
        figure(args.figure, args.out, args.steps, args.seed)
    if args.codes:
        codes(args.seeds)


if __name__ == "__main__":
    main()
