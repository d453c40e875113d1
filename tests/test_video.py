"""`drrl render`'s video module on the cart-pole, which draws its frames in NumPy (Baxter's: tests/test_baxter.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from PIL import Image

from drrl.policies import linear
from drrl.video import check_video_path, record_episode, write_video

# a small Pendulum run: a generation of 8 one-episode candidates (Pendulum's own defaults spend 512 a generation)
PENDULUM_RUN = ["train", "--env", "Pendulum-v1", "--popsize", "8", "--episodes-per-candidate", "1", "--budget", "16"]
PENDULUM_RUN += ["--eval-episodes", "2", "--quiet"]


def test_a_cartpole_episode_becomes_a_gif_at_half_the_control_rate(tmp_path):
    env = gym.make("drrl/CartPole-v0", render_mode="rgb_array")
    policy = linear(4, 1)
    recording = record_episode(policy, torch.zeros(policy.num_params), env, seed=3, fps=25, max_steps=10)
    env.close()
    assert recording.steps == 10 and recording.fps == 25  # the cart-pole runs at 50 steps per second
    assert len(recording.frames) == 6 and recording.frames[0].shape == (400, 600, 3)  # the start and every 2nd step
    write_video(recording.frames, tmp_path / "cartpole.gif", recording.fps)
    with Image.open(tmp_path / "cartpole.gif") as gif:
        assert gif.n_frames == 6 and gif.info["duration"] == 40


def test_video_paths_are_checked_before_any_work(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match=r"unsupported video format '\.webm'.*\.gif, \.mp4"):
        check_video_path(tmp_path / "x.webm")
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if the render extra were not installed
    with pytest.raises(ImportError, match=r"pip install 'drrl\[render\]'"):
        check_video_path(tmp_path / "x.mp4")
    assert check_video_path(tmp_path / "x.GIF").name == "x.GIF"
    with pytest.raises(ValueError, match="no frames"):
        write_video([], tmp_path / "x.gif", fps=25)


def test_an_mp4_is_written_with_imageio_ffmpeg(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="the render extra is not installed")
    frames = [np.full((64, 96, 3), 40 * k, dtype=np.uint8) for k in range(5)]
    write_video(frames, tmp_path / "clip.mp4", fps=25)
    assert (tmp_path / "clip.mp4").read_bytes()[4:8] == b"ftyp"  # an MP4 container


def test_render_of_an_env_that_needs_pygame_says_what_to_install(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from drrl.cli import main

    out = tmp_path / "run"
    trained = CliRunner().invoke(
        main,
        [*PENDULUM_RUN, "--out", str(out)],
    )
    assert trained.exit_code == 0, trained.output
    monkeypatch.setitem(sys.modules, "pygame", None)  # as if gymnasium[classic_control] were not installed
    result = CliRunner().invoke(main, ["render", str(out), "--out", str(tmp_path / "x.gif")])
    assert result.exit_code == 1 and 'pip install "gymnasium[classic_control]"' in result.output, result.output
    assert "Traceback" not in result.output and not (tmp_path / "x.gif").exists()


@pytest.mark.slow
def test_render_of_a_pygame_env_is_headless_and_quiet(tmp_path):
    """Gymnasium's pygame envs draw in memory: no display session is needed, and SDL is not let complain of one."""
    pytest.importorskip("pygame", reason="gymnasium[classic_control] is not installed")
    drrl = [sys.executable, "-c", "from drrl.cli import main; main()"]
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "SDL_VIDEODRIVER", "DISPLAY")}
    train = [*PENDULUM_RUN, "--out", "run"]
    subprocess.run([*drrl, *train], cwd=tmp_path, env=env, check=True, capture_output=True)
    render = subprocess.run(
        [*drrl, "render", "run", "--max-steps", "4", "--out", "x.gif"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    assert render.returncode == 0 and (tmp_path / "x.gif").exists(), render.stderr
    assert "XDG_RUNTIME_DIR" not in render.stderr and "error" not in render.stderr.lower(), render.stderr
