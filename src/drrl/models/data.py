"""Real episodes for the world model: recorded from any batched env, kept in a buffer, cut into unfolding windows.

An episode of n steps holds observations o_0..o_n, actions a_0..a_{n−1}, rewards r_1..r_n and whether it ended by
termination (failure or success) rather than by a time limit. A window (3.3.1) is L = unfold + overshoot
consecutive steps of one episode from a start i: its first ``unfold`` steps are observed, the rest are the
overshooting part (3.3.2). Every start with a full observed part is used; an overshooting part that runs past the
episode's end is masked there, so short (often failed, and informative) episodes still teach the model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv, VectorWrapper

# The change scale of a feature that never changed within an episode (Baxter's targets): the model multiplies its
# predicted change by the scale, so such a feature stays where it is, whatever the model's read-out. A scale of 1
# (as for the other normalisations) would let read-out errors of order one move it by whole units at every
# imagined step, and those moves, fed back as inputs, ruined every prediction made from them (the k-step errors of
# Baxter's joint angles fell from 0.17 to 0.007 rad at 20 steps on the episodes fitted, with this floor).
STILL = 1e-6

# (observations (N, o), actions (M, a)) -> their mirror images under a task's reflection symmetry, which leaves
# rewards and ends as they are (drrl.envs.registry.EnvEntry.mirror)
Mirror = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Episode:
    observations: np.ndarray  # (n + 1, o) float32, or frames (n + 1, F, H, W) uint8
    actions: np.ndarray  # (n, a) float32
    rewards: np.ndarray  # (n,) float32
    terminated: bool  # ended by failure or success, not by a time limit

    def __len__(self) -> int:
        return len(self.actions)

    def ends(self) -> np.ndarray:
        """(n,) float32: 1.0 at the step that ended the episode by termination, else 0.0."""
        ends = np.zeros(len(self), dtype=np.float32)
        ends[-1] = float(self.terminated)
        return ends


@dataclass(frozen=True)
class Windows:
    """Unfolding windows, stacked: W windows of L steps."""

    observations: torch.Tensor  # (W, L, o): o_i..o_{i+L−1}
    actions: torch.Tensor  # (W, L, a)
    next_observations: torch.Tensor  # (W, L, o): the targets o_{i+1}..o_{i+L}
    rewards: torch.Tensor  # (W, L)
    ends: torch.Tensor  # (W, L) 1.0 where the episode terminates
    mask: torch.Tensor  # (W, L) 1.0 where the step lies inside its episode
    previous_actions: torch.Tensor  # (W, a): a_{i−1}, the action before the window (0 at an episode's start)

    def __len__(self) -> int:
        return self.actions.shape[0]

    def to(self, device) -> Windows:
        return Windows(*(getattr(self, name).to(device) for name in self.__dataclass_fields__))

    def select(self, index: torch.Tensor) -> Windows:
        return Windows(*(getattr(self, name)[index] for name in self.__dataclass_fields__))


class EpisodeBuffer:
    """The real episodes seen so far."""

    def __init__(self, episodes: Sequence[Episode] = ()):
        self.episodes: list[Episode] = []
        self.extend(episodes)

    def extend(self, episodes: Sequence[Episode]) -> None:
        for episode in episodes:
            if len(episode) < 1:
                raise ValueError("an episode needs at least one step")
            self.episodes.append(episode)

    def __len__(self) -> int:
        return len(self.episodes)

    @property
    def num_steps(self) -> int:
        return sum(len(episode) for episode in self.episodes)

    def start_observations(self) -> np.ndarray:
        """o_0 of every episode, (E, o): the real start states imagination resets to."""
        return np.stack([episode.observations[0] for episode in self.episodes])

    def check_unfolding(self, unfold: int, overshoot: int) -> None:
        """Raise a clear error when no episode holds one full window of ``unfold`` + ``overshoot`` steps."""
        if unfold < 1 or overshoot < 0:
            raise ValueError(f"unfold must be >= 1 and overshoot >= 0, got unfold={unfold}, overshoot={overshoot}")
        longest = max((len(episode) for episode in self.episodes), default=0)
        if longest < unfold:
            raise ValueError(
                f"the data is too short for the unfolding: unfolding {unfold} steps needs an episode of "
                f"at least {unfold} steps, but the longest of the {len(self)} episode(s) has {longest}"
            )
        if longest < unfold + overshoot:
            raise ValueError(
                f"the overshooting horizon is longer than the data: {unfold} unfolded + {overshoot} "
                f"overshooting steps need an episode of at least {unfold + overshoot} steps, but the "
                f"longest of the {len(self)} episode(s) has {longest}; lower the overshoot or collect "
                f"longer episodes"
            )

    def windows(self, unfold: int, overshoot: int) -> Windows:
        """Every window of ``unfold`` observed + ``overshoot`` overshooting steps (see the module docstring).

        Needs one episode of at least ``unfold`` steps; ``check_unfolding`` is the stricter check for
        training data, which must also hold one full window.
        """
        longest = max((len(episode) for episode in self.episodes), default=0)
        if longest < unfold:
            self.check_unfolding(unfold, overshoot)
        length = unfold + overshoot
        pieces = [_episode_windows(episode, unfold, length) for episode in self.episodes if len(episode) >= unfold]
        return Windows(*(torch.as_tensor(np.concatenate(parts)) for parts in zip(*pieces, strict=True)))

    def window_episodes(self, unfold: int) -> np.ndarray:
        """The episode (its index in the buffer) of each of ``windows``' windows, in their order."""
        counts = [max(len(episode) - unfold + 1, 0) for episode in self.episodes]
        return np.repeat(np.arange(len(self.episodes)), counts)

    def scales(self) -> dict[str, torch.Tensor]:
        """Normalisation for ``WorldModel.set_scales``: means and standard deviations of the data."""
        observations = np.concatenate([episode.observations for episode in self.episodes])
        changes = np.concatenate([np.diff(episode.observations, axis=0) for episode in self.episodes])
        rewards = np.concatenate([episode.rewards for episode in self.episodes])
        return {
            "observation_mean": torch.as_tensor(observations.mean(0)),
            "observation_scale": torch.as_tensor(_positive(observations.std(0))),
            "change_scale": torch.as_tensor(_positive(changes.std(0), STILL)),
            "reward_mean": torch.as_tensor(rewards.mean()),
            "reward_scale": torch.as_tensor(_positive(rewards.std())),
        }

    def state_dict(self) -> dict:
        """All episodes as four concatenated tensors and their lengths (no pickling)."""
        return {
            "observations": torch.as_tensor(np.concatenate([e.observations for e in self.episodes])),
            "actions": torch.as_tensor(np.concatenate([e.actions for e in self.episodes])),
            "rewards": torch.as_tensor(np.concatenate([e.rewards for e in self.episodes])),
            "lengths": torch.tensor([len(e) for e in self.episodes]),
            "terminated": torch.tensor([e.terminated for e in self.episodes]),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> EpisodeBuffer:
        lengths = state["lengths"].tolist()
        observations = np.split(state["observations"].numpy(), np.cumsum([n + 1 for n in lengths])[:-1])
        actions = np.split(state["actions"].numpy(), np.cumsum(lengths)[:-1])
        rewards = np.split(state["rewards"].numpy(), np.cumsum(lengths)[:-1])
        return cls(
            [
                Episode(o, a, r, bool(t))
                for o, a, r, t in zip(observations, actions, rewards, state["terminated"].tolist(), strict=True)
            ]
        )


def with_mirror_images(buffers: Sequence[EpisodeBuffer], mirror: Mirror) -> list[EpisodeBuffer]:
    """Each of ``buffers`` with the mirror image of each of its episodes appended: episodes the env would have given
    the mirrored actions, with the same rewards and ends. An episode's image is one object wherever the episode
    appears, so that parts of a buffer stay parts of it (``drrl.models.fit`` finds windows by episode)."""
    images: dict[int, Episode] = {}

    def image(episode: Episode) -> Episode:
        if id(episode) not in images:
            observations, actions = mirror(episode.observations, episode.actions)
            images[id(episode)] = replace(episode, observations=observations, actions=actions)
        return images[id(episode)]

    return [EpisodeBuffer([*buffer.episodes, *map(image, buffer.episodes)]) for buffer in buffers]


def _positive(std: np.ndarray, constant: float = 1.0) -> np.ndarray:
    """A standard deviation safe to divide by: constant features get ``constant``."""
    return np.where(std > 1e-6, std, constant).astype(np.float32)


def _episode_windows(episode: Episode, unfold: int, length: int) -> tuple[np.ndarray, ...]:
    """The windows of one episode, padded past its end (and masked there)."""
    n = len(episode)
    starts = np.arange(n - unfold + 1)
    steps = starts[:, None] + np.arange(length)  # (W, L) step indices, possibly past the end
    mask = steps < n
    inside = np.minimum(steps, n - 1)
    ends = episode.ends()
    return (
        episode.observations[inside],
        episode.actions[inside],
        episode.observations[inside + 1],
        episode.rewards[inside],
        ends[inside] * mask,
        mask.astype(np.float32),
        np.concatenate([np.zeros_like(episode.actions[:1]), episode.actions])[starts],
    )


def model_actions(actions, space: spaces.Space) -> np.ndarray:
    """Actions as the world model reads them, (N, a) float32: a Box's values, a Discrete's choice one-hot."""
    if isinstance(space, spaces.Discrete):
        choices = np.asarray(actions, dtype=np.int64).reshape(-1) - int(space.start)
        return np.eye(int(space.n), dtype=np.float32)[choices]
    actions = np.asarray(actions, dtype=np.float32)
    return actions.reshape(len(actions), -1)


def action_size(space: spaces.Space) -> int:
    """The length of ``model_actions``' rows for ``space``."""
    return int(space.n) if isinstance(space, spaces.Discrete) else int(np.prod(space.shape or ()))


class EpisodeRecorder(VectorWrapper):
    """Records the first episode of every sub-environment while ``drrl.rollout.evaluate`` (or anyone) steps it.

    The actions recorded are those the env receives (after the policy's outputs are bounded; a Discrete choice
    one-hot), so the model learns the env's own response to them. Later episodes of a sub-environment (after its
    autoreset) are not recorded. Observations are kept as float32, frames (uint8) as they are.
    """

    def __init__(self, env: VectorEnv):
        super().__init__(env)
        space_type = env.single_observation_space.dtype
        self._dtype = np.uint8 if space_type == np.uint8 else np.float32
        self._reset_records()

    def _reset_records(self) -> None:
        self._observations: list[list[np.ndarray]] = [[] for _ in range(self.num_envs)]
        self._actions: list[list[np.ndarray]] = [[] for _ in range(self.num_envs)]
        self._rewards: list[list[float]] = [[] for _ in range(self.num_envs)]
        self._terminated = np.zeros(self.num_envs, dtype=bool)
        self._recording = np.ones(self.num_envs, dtype=bool)

    def reset(self, **kwargs):
        observations, info = self.env.reset(**kwargs)
        self._reset_records()
        for i in range(self.num_envs):
            self._observations[i].append(np.array(observations[i], dtype=self._dtype))
        return observations, info

    def step(self, actions):
        observations, rewards, terminated, truncated, info = self.env.step(actions)
        actions = model_actions(actions, self.single_action_space)
        for i in np.flatnonzero(self._recording):
            self._observations[i].append(np.array(observations[i], dtype=self._dtype))
            self._actions[i].append(actions[i])
            self._rewards[i].append(float(rewards[i]))
        self._terminated |= self._recording & terminated
        self._recording &= ~(terminated | truncated)
        return observations, rewards, terminated, truncated, info

    def episodes(self) -> list[Episode]:
        """The recorded episodes with at least one step, in sub-environment order."""
        return [
            Episode(
                np.stack(self._observations[i]),
                np.stack(self._actions[i]),
                np.asarray(self._rewards[i], dtype=np.float32),
                bool(self._terminated[i]),
            )
            for i in range(self.num_envs)
            if self._actions[i]
        ]
