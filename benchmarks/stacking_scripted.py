"""The stacking tasks done by the scripted stacker (``drrl.envs.baxter.scripted``): what each task asks, in numbers.

For each task (a stack of two or three, fixed or random positions, end-point actions), 50 fresh episodes (seeds 0–49,
one batch): the fraction whose stack stood for one second, and the median time until it stood. With ``--video``,
the first episode of the stack of three at random positions is recorded (GIF or MP4).

    python benchmarks/stacking_scripted.py --video docs/images/baxter_stack_scripted.gif
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.stack_env import BaxterStackEnv, BaxterStackVectorEnv
from drrl.envs.baxter.stacking import HORIZON
from drrl.video import write_video

TASKS = {
    "stack of two, fixed positions": {"blocks": 2},
    "stack of two, random positions": {"blocks": 2, "positions": "random"},
    "stack of three, fixed positions": {"blocks": 3},
    "stack of three, random positions": {"blocks": 3, "positions": "random"},
}


def run(options: dict, episodes: int) -> np.ndarray:
    """The control step at which each episode's stack stood (−1: never)."""
    env = BaxterStackVectorEnv(episodes, controller="end_point", **options)
    observations, _ = env.reset(seed=list(range(episodes)))
    stacker = ScriptedStacker(env.task)
    stood, over = np.full(episodes, -1), np.zeros(episodes, dtype=bool)
    for step in range(1, HORIZON + 1):
        observations, _, terminated, truncated, info = env.step(stacker.act(observations))
        stood = np.where(info["stacked"] & ~over, step, stood)
        over |= terminated | truncated
        if over.all():
            break
    return stood


def record(options: dict, path: str, every: int = 10) -> None:
    """One episode (seed 0), a frame every ``every`` control steps, written to ``path``."""
    env = BaxterStackEnv(render_mode="rgb_array", controller="end_point", width=256, height=192, **options)
    observation, _ = env.reset(seed=0)
    stacker, frames = ScriptedStacker(env.task), [env.render()]
    for step in range(1, HORIZON + 1):
        observation, _, terminated, truncated, _ = env.step(stacker.act(observation[None])[0])
        if step % every == 0 or terminated or truncated:
            frames.append(env.render())
        if terminated or truncated:
            break
    write_video(frames, path, fps=100 / every)
    print(f"wrote {path}: {len(frames)} frames, {step / 100:.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--video", default=None, help="record episode 0 of the stack of three at random positions")
    args = parser.parse_args()
    print("| task | stood | median time to a standing stack | wall s |")
    print("| --- | --- | --- | --- |")
    for name, options in TASKS.items():
        start = time.perf_counter()
        stood = run(options, args.episodes)
        seconds = np.median(stood[stood > 0]) * 0.01 if (stood > 0).any() else float("nan")
        print(f"| {name} | {(stood > 0).mean():.0%} | {seconds:.2f} s | {time.perf_counter() - start:.1f} |")
    if args.video:
        record(TASKS["stack of three, random positions"], args.video)


if __name__ == "__main__":
    main()
