"""The learned model as a batched environment: a Gymnasium ``VectorEnv`` that PGPE searches in unchanged.

Every sub-environment starts from a real start observation drawn from the buffer, with a member of the ensemble
drawn at reset (an episode restarted later keeps its env's member), and then lives in the model: each step feeds the
current (predicted) observation and the policy's action to the model, which is dynamical consistency (3.3.3) at
imagination time. Rewards and ends come either from the task's reward in closed form applied to the predicted
observations (``TaskKnowledge.reward``, e.g. the thesis's 5.8, from drrl's environment registry), less the cost of
the action where the task charges it (``action_cost``, e.g. Reacher's ‖a‖²), or from the model's reward and end
heads. Where some observation entries follow in closed form from the others (``complete_observation``, e.g. Baxter's
end-point offsets from its joint angles), each prediction is completed by it before anything reads it. Nothing here
touches the real environment: imagined steps cost no real samples, and the training loop counts them apart.

Episode seeds (``reset(seed=[...])``, one per sub-environment) fix each episode's start and member, so candidates of
one PGPE generation are compared on the same imagined starts, as they are on real ones.

Each episode is stepped by its own member only: the episodes are grouped by member into an (A, G) batch of the A
members drawn, G the largest group, so an ensemble of K costs about what one model does (a generation's episodes
that share their seeds share one member, and only that one is stepped). With a disagreement penalty every member
steps every episode, since the penalty needs all their predictions.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from drrl.models.base import LearnedModel, members_of, rebuilt, weights
from drrl.models.data import model_actions
from drrl.models.outcome import EndReward
from drrl.models.recurrent import WorldModel
from drrl.models.remembering import memory_space

# (next observations (N, o), 1-based steps (N,)) -> (rewards (N,), terminated (N,)): a task's reward in closed form,
# as drrl's environment registry holds it (drrl.envs.registry.EnvEntry.reward)
RewardFunction = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
# actions (N, a) -> the reward's share that depends on them, as a cost (N,) (EnvEntry.action_cost)
ActionCost = Callable[[np.ndarray], np.ndarray]
# (observations (N, o), predicted next observations (N, o)) -> the next ones with the entries that follow from the
# rest recomputed (EnvEntry.complete_observation)
ObservationFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TaskKnowledge:
    """What imagined episodes know of the task beside the model, each None where nothing is known (the model's own
    reward and end heads are used where ``reward`` is None). Frozen and small, it travels to rollout workers with
    the ``ImaginedWorld``."""

    reward: RewardFunction | None = None  # reward and end in closed form (e.g. 5.8), or learned (``LearnedOutcome``)
    action_cost: ActionCost | None = None  # the reward's share that depends on the action, taken from ``reward``
    complete_observation: ObservationFunction | None = None  # recomputes the entries that follow from the others
    end_reward: EndReward | None = None  # a terminating step's reward where the step alone decides it (5.8's failure)


@dataclass(frozen=True)
class ImaginedWorld:
    """What an ``ImaginedEnv`` is made of, small enough to send to another process: the model's settings and
    weights, the real start observations and the task's horizon and knowledge. ``make`` builds the env (an
    ``EnvSource`` of drrl.envs.batch), so that rollout workers can step imagined episodes as they step real ones."""

    model_type: type  # a LearnedModel class, e.g. drrl.models.recurrent.WorldModel
    model_settings: dict
    model_state: dict[str, torch.Tensor]
    start_observations: np.ndarray
    action_space: spaces.Space
    horizon: int
    task: TaskKnowledge = TaskKnowledge()
    disagreement_penalty: float = 0.0
    memory: bool = False

    @classmethod
    def of(
        cls,
        model: LearnedModel,
        start_observations: np.ndarray,
        action_space: spaces.Space,
        horizon: int,
        task: TaskKnowledge = TaskKnowledge(),
        disagreement_penalty: float = 0.0,
        memory: bool = False,
    ) -> ImaginedWorld:
        return cls(
            type(model),
            model.settings(),
            weights(model),
            np.asarray(start_observations, dtype=np.float32),
            action_space,
            horizon,
            task,
            disagreement_penalty,
            memory,
        )

    def make(self, num_envs: int) -> ImaginedEnv:
        return ImaginedEnv(
            rebuilt(self.model_type, self.model_settings, self.model_state),
            self.start_observations,
            num_envs,
            self.action_space,
            self.horizon,
            self.task,
            self.disagreement_penalty,
            self.memory,
        )


class ImaginedEnv(VectorEnv):
    """``num_envs`` imagined episodes stepped together by a learned model, with next-step autoreset.

    Args:
        model: the world model(s); a member is drawn per env at reset.
        start_observations: real start observations (S, o) to reset from.
        action_space: the real env's single action space (the policy's actions pass through unchanged).
        horizon: steps after which an imagined episode is truncated (the real task's).
        task: the reward and end, action cost and observation completion known beside the model; the model's own
            reward and end heads (end when p̂ > 0.5) where no reward is known.
        disagreement_penalty: λ in r ← r − λ · disagreement (``model.disagreement``), 0 for none.
        memory: observations are [ô_t, h_{t−1}], the prediction and the state it was predicted from (the model's
            ``memory``, ``drrl.models.remembering``), for a policy that reads the model's memory.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        model: LearnedModel,
        start_observations: np.ndarray,
        num_envs: int,
        action_space: spaces.Space,
        horizon: int,
        task: TaskKnowledge = TaskKnowledge(),
        disagreement_penalty: float = 0.0,
        memory: bool = False,
    ):
        starts = np.array(start_observations, dtype=np.float32)  # a copy: a Ray worker's arrays are read-only
        if starts.ndim != 2 or len(starts) == 0:
            raise ValueError(f"start_observations must be a non-empty (S, o) array, got shape {starts.shape}")
        self.model = model
        self.num_envs = num_envs
        self.horizon = horizon
        self.task = task
        self.disagreement_penalty = disagreement_penalty
        self.memory = memory
        self.device = model.device
        self._starts = torch.as_tensor(starts, device=self.device)
        bound = np.finfo(np.float32).max
        self.single_observation_space = spaces.Box(-bound, bound, (starts.shape[1],), np.float32)
        if memory:
            if not isinstance(model, WorldModel):
                raise ValueError(f"only a recurrent world model has a memory for the policy to read, not {type(model)}")
            self.single_observation_space = memory_space(starts.shape[1], model)
        self.single_action_space = action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(action_space, num_envs)
        self._rng = np.random.default_rng()
        self._observation: torch.Tensor | None = None
        self._every_member = bool(disagreement_penalty) or len(model) == 1  # every member steps every env
        self._member = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        # the members that step (the model, or those drawn), the (A, G) envs each of them steps (N pads a group),
        # env n's row (its member's) and place in that layout, and the state (A, G, ·) in it
        self._stepping = model
        self._slots = torch.zeros(len(model), 1, dtype=torch.long, device=self.device)
        self._row = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._position = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._state: list[torch.Tensor] = []
        self._observed = torch.ones(num_envs, dtype=torch.bool, device=self.device)  # o_t is a real start
        self.elapsed_steps = np.zeros(num_envs, dtype=np.int64)
        self._ended = np.zeros(num_envs, dtype=bool)

    def reset(self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None):
        """Start every env from a real start observation, with a member drawn per env."""
        if seed is None or isinstance(seed, (int, np.integer)):
            if seed is not None:
                self._rng = np.random.default_rng(int(seed))
            starts, members = self._draw(self._rng, self.num_envs)
        else:
            if len(seed) != self.num_envs:
                raise ValueError(f"expected one seed per env ({self.num_envs}), got {len(seed)}")
            drawn = {s: self._draw(np.random.default_rng(s), 1) for s in set(map(int, seed))}
            starts = np.concatenate([drawn[int(s)][0] for s in seed])
            members = np.concatenate([drawn[int(s)][1] for s in seed])
            self._rng = np.random.default_rng([int(s) for s in seed])  # for autoresets only
        self._observation = self._starts[torch.as_tensor(starts, device=self.device)]
        self._member = torch.as_tensor(members, device=self.device)
        self._group()
        self._state = self._stepping.initial_state(self._slots.shape[1])
        self._observed[:] = True
        self.elapsed_steps[:] = 0
        self._ended[:] = False
        return self._observed_now(), {}

    @torch.inference_mode()
    def step(self, actions):
        """One imagined step of every env; envs that ended on the previous step restart instead (their action is
        ignored, reward 0, terminated and truncated False: Gymnasium's next-step autoreset)."""
        if self._observation is None:
            raise RuntimeError("call reset() before step()")
        action = torch.as_tensor(model_actions(actions, self.single_action_space), device=self.device)
        prediction, self._state = self._stepping.step(
            self._grouped(self._observation), self._grouped(action), self._state, self._grouped(self._observed)
        )
        previous, self._observation = self._observation, self._own(prediction.observations)
        task = self.task
        if task.complete_observation is not None:
            completed = task.complete_observation(previous.cpu().numpy(), self._observation.cpu().numpy())
            self._observation = torch.as_tensor(completed, dtype=previous.dtype, device=self.device)
        self.elapsed_steps += 1
        if task.reward is not None:
            reward, terminated = task.reward(self._observation.cpu().numpy(), self.elapsed_steps)
            if task.action_cost is not None:
                reward = reward - task.action_cost(action.cpu().numpy())
        else:
            reward = self._own(prediction.rewards).cpu().numpy().astype(np.float64)
            terminated = self._own(prediction.ends).cpu().numpy() > 0.5
        if self.disagreement_penalty:
            reward = reward - self.disagreement_penalty * self.model.disagreement(prediction).cpu().numpy()
        truncated = self.elapsed_steps >= self.horizon
        self._observed[:] = False
        restarting = self._ended.nonzero()[0]
        if restarting.size:
            self._restart(restarting)
            reward[restarting], terminated[restarting], truncated[restarting] = 0.0, False, False
        self._ended = terminated | truncated
        return self._observed_now(), reward, terminated, truncated, {}

    def _observed_now(self) -> np.ndarray:
        """What the policy reads: the current observations, with each env's memory of its own member if asked."""
        assert self._observation is not None
        if not self.memory:
            return self._observation.cpu().numpy()
        assert isinstance(self._stepping, WorldModel)
        memory = self._own(self._stepping.memory(self._state))
        return torch.cat([self._observation, memory], dim=1).cpu().numpy()

    def _draw(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n (start index, member) pairs."""
        return rng.integers(len(self._starts), size=n), rng.integers(len(self.model), size=n)

    def _restart(self, envs: np.ndarray) -> None:
        """New episodes in ``envs`` from fresh real starts; each keeps its env's member, so the layout stays (were
        members drawn again, those whose episodes end late would gather ever more envs)."""
        starts, _members = self._draw(self._rng, len(envs))  # members drawn and unused: the starts' stream stays
        index = torch.as_tensor(envs, device=self.device)
        assert self._observation is not None  # restarts follow a reset
        # out of place: the observations handed out by the previous step must not change
        self._observation = self._observation.index_put(
            (index,), self._starts[torch.as_tensor(starts, device=self.device)]
        )
        self._observed[index] = True
        self.elapsed_steps[envs] = 0
        rows = (slice(None), index) if self._every_member else (self._row[index], self._position[index])
        for tensor in self._state:
            tensor[rows] = 0.0

    def _grouped(self, rows: torch.Tensor) -> torch.Tensor:
        """Per-env ``rows`` (N, …) in the members' layout (A, G, …); as they are if every member steps every env."""
        if self._every_member:
            return rows
        return rows.unsqueeze(0) if self._one_row else _padded(rows)[self._slots]

    @property
    def _one_row(self) -> bool:
        """One member steps every env, in order: the layout is the envs' own, (1, N)."""
        return self._slots.shape[0] == 1

    def _own(self, predicted: torch.Tensor) -> torch.Tensor:
        """(N, …) each env's row of ``predicted`` (A, G, …), its own member's (the layout's row 0 if there is one)."""
        return predicted[0] if self._one_row else predicted[self._row, self._position]

    def _group(self) -> None:
        """Which envs each member steps: all of them for the disagreement penalty, else its own episodes, padded
        with the scratch row N to the largest group; a member drawn for no env is not stepped at all."""
        members, n = len(self.model), self.num_envs
        if self._every_member:
            self._stepping, self._row = self.model, self._member
            self._slots = torch.arange(n, device=self.device).expand(members, n)
            self._position = torch.arange(n, device=self.device)
            return
        drawn, self._row = torch.unique(self._member, sorted=True, return_inverse=True)
        self._stepping = self.model if len(drawn) == members else members_of(self.model, drawn)
        order = torch.argsort(self._row, stable=True)
        counts = torch.bincount(self._row)
        first = torch.cumsum(counts, 0) - counts  # where each row's envs begin in ``order``
        position = torch.arange(n, device=self.device) - first[self._row[order]]
        self._slots = torch.full((len(drawn), int(counts.max())), n, dtype=torch.long, device=self.device)
        self._slots[self._row[order], position] = order
        self._position = torch.empty_like(position)
        self._position[order] = position


def _padded(rows: torch.Tensor) -> torch.Tensor:
    """``rows`` (N, …) with a row of zeros appended, the scratch row N that pads the groups."""
    return torch.cat([rows, rows.new_zeros(1, *rows.shape[1:])])
