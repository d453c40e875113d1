"""Videos of a trained policy (``drrl render``): one episode of a run's centre policy as a GIF or an MP4.

Any environment that draws ``rgb_array`` frames works: drrl's cart-poles draw in NumPy, Baxter through MuJoCo's
OpenGL renderer, headless (EGL, else OSMesa: ``drrl.envs.baxter.render``). GIFs are written with Pillow
(installed with matplotlib); MP4s (H.264) with imageio-ffmpeg, the optional extra ``drrl[render]``, which ships its
own ffmpeg binary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium.vector import SyncVectorEnv, VectorEnv, VectorWrapper

from drrl.envs.batch import ActionMap, missing_dependency
from drrl.envs.registry import lookup
from drrl.envs.rendered import following_env, rendering_env
from drrl.policies import Policy, make_policy
from drrl.rollout import evaluate
from drrl.runs import RunFolder, check_writable
from drrl.training.train import as_read, check_same_spaces, open_run, policy_inputs, trained_center

VIDEO_FORMATS = (".gif", ".mp4")
INSTALL_MP4 = "writing MP4 needs imageio-ffmpeg: pip install 'drrl[render]' (or write a .gif)"


@dataclass(frozen=True)
class Recording:
    """One recorded episode: its frames, their rate and what the episode earned."""

    frames: list[np.ndarray]
    fps: float
    episode_return: float
    steps: int
    info: dict[str, Any]  # the last step's info (Baxter: "distance", the largest end-point distance in metres)


def check_video_path(path: Path | str) -> Path:
    """``path`` if drrl can write a video there; raises ValueError (format) or ImportError (MP4 without the extra)
    before any work is done."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise ValueError(f"unsupported video format {path.suffix!r} of {path}; use one of {', '.join(VIDEO_FORMATS)}")
    if path.suffix.lower() == ".mp4":
        _mp4_writer()
    check_writable(path, "video", folder=False)
    return path


def _mp4_writer():
    """The ``imageio_ffmpeg`` module, or an ImportError that says how to install it."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise ImportError(INSTALL_MP4) from None
    return imageio_ffmpeg


def write_video(frames: list[np.ndarray], path: Path | str, fps: float) -> Path:
    """Write RGB frames (height, width, 3), uint8, to ``path``: a looping GIF or an MP4."""
    path = check_video_path(path)
    if not frames:
        raise ValueError("no frames to write")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return _write_frames(frames, path, fps)
    except OSError as error:  # a full disk, a folder removed meanwhile
        raise ValueError(f"cannot write {path}: {error.strerror or error}") from None


def _write_frames(frames: list[np.ndarray], path: Path, fps: float) -> Path:
    if path.suffix.lower() == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
        return path
    height, width = frames[0].shape[:2]
    writer = _mp4_writer().write_frames(str(path), (width, height), fps=fps, macro_block_size=8, quality=7)
    writer.send(None)  # start ffmpeg
    try:
        for frame in frames:
            writer.send(np.ascontiguousarray(frame).tobytes())
    finally:
        writer.close()
    return path


class FrameRecorder(VectorWrapper):
    """A one-env vector env that keeps frames of its episode: at the reset, every ``period``-th step while the episode
    runs, and at its end; and the last step's info."""

    def __init__(self, env: gymnasium.Env, period: int):
        super().__init__(SyncVectorEnv([lambda: env]))
        self.single, self.period = env, period
        self.frames: list[np.ndarray] = []
        self.steps, self.ended = 0, False
        self.info: dict = {}

    def reset(self, **kwargs):
        observations, infos = self.env.reset(**kwargs)
        self.frames, self.steps, self.ended = [self.single.render()], 0, False
        return observations, infos

    def step(self, actions):
        observations, rewards, terminated, truncated, infos = self.env.step(actions)
        if not self.ended:  # later steps only restart the env (next-step autoreset)
            self.steps += 1
            self.ended = bool(terminated[0] or truncated[0])
            self.info = {key: value[0] for key, value in infos.items() if not key.startswith("_")}
            if self.steps % self.period == 0 or self.ended:
                self.frames.append(self.single.render())
        return observations, rewards, terminated, truncated, infos


def record_episode(
    policy: Policy,
    center: torch.Tensor,
    env: gymnasium.Env,
    *,
    seed: int = 0,
    fps: float = 25.0,
    max_steps: int | None = None,
    read: Callable[[VectorEnv], VectorEnv] | None = None,
) -> Recording:
    """Run the policy ``center`` (n,) for one episode of ``env`` (render_mode "rgb_array") through the rollout that
    trains and measures (``drrl.rollout.evaluate``, episode seed from ``seed``), keeping a frame at the start,
    then every k-th step, k = the env's ``render_fps`` / ``fps`` rounded (at least 1), and at the end. ``read``
    gives the env as the policy reads it (a frame encoder in front, ``drrl.training.train.as_read``)."""
    rate = env.metadata.get("render_fps", fps)
    recorder = FrameRecorder(env, period=max(1, round(rate / fps)))
    seen = recorder if read is None else read(recorder)
    result = evaluate(policy, center.reshape(1, -1), seen, 1, seed=seed, max_steps=max_steps)
    return Recording(recorder.frames, rate / recorder.period, float(result.returns[0]), result.steps, recorder.info)


def render_run(
    run_path: Path | str,
    out: Path | str,
    *,
    final: bool = False,
    seed: int = 0,
    fps: float = 25.0,
    max_steps: int | None = None,
    env_name: str | None = None,
    **env_options: Any,
) -> Recording:
    """Record one episode of a run folder's best measured (or, with ``final``, last) centre policy to ``out``, cut
    at ``max_steps`` (default: the run's own ``max_steps``, if it had one), on the env it trained on or on
    ``env_name``, which must have the same spaces (e.g. the stand-in of the robot it trained on); a Gymnasium MuJoCo
    body is followed by its model's tracking camera (``drrl.envs.rendered.following_env``).

    ``env_options`` go to ``gymnasium.make`` (Baxter: ``width``, ``height``, ``shadows``)."""
    out = check_video_path(out)
    folder = RunFolder(Path(run_path))
    config, checkpoint = open_run(folder)
    env_id = lookup(checkpoint["env_id"] if env_name is None else env_name).env_id
    env = following_env(env_id, env_options)
    if env_name is not None:
        trained_on = rendering_env(lookup(checkpoint["env_id"]).env_id, env_options)
        trained_on.close()
        try:
            check_same_spaces(
                checkpoint["env_id"],
                (trained_on.observation_space, trained_on.action_space),
                env_id,
                (env.observation_space, env.action_space),
            )
        except ValueError:
            env.close()
            raise
    try:
        inputs = policy_inputs(config, env.observation_space)
        policy = make_policy(config.policy, inputs, ActionMap(env.action_space).size)
        center = trained_center(checkpoint, policy, final)
        recording = record_episode(
            policy,
            center,
            env,
            seed=seed,
            fps=fps,
            max_steps=max_steps or config.max_steps,
            read=partial(as_read, config, checkpoint),
        )
    except (ImportError, gymnasium.error.DependencyNotInstalled) as error:  # drawing needs pygame, say
        raise ValueError(f"{env_id} cannot draw frames here: {missing_dependency(env_id, error)}") from None
    finally:
        env.close()
    write_video(recording.frames, out, recording.fps)
    return recording
