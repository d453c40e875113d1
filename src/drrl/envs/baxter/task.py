"""The reach task after the thesis (5.2, reward 5.10): bring each gripper end-point to its target and hold it there.

Reading of 5.10. The thesis prints the cart-pole's reward (5.8) again with a horizon of 2000, in the cart-pole's
variables (|s|, |θ| ≤ 0.05), for a task it describes as "reach a certain position as fast as possible". We read it
as: after each transition at 1-based step t ≤ T = 2000,

    r_t = 0             if every end-point is within 0.05 m of its target,
    r_t = −1            otherwise,
    r_t = −2·(T − t)    on failure, which ends the episode: an arm touching the table, the body or the other arm,
                        or a joint at its position limit.

So the return counts the steps spent away from the target(s), and a failure costs twice the remaining steps: more
than any episode that avoids it. The horizon counts control steps, not seconds: T = 2000 keeps the thesis's
number and the scale of its penalty whatever the control period. We choose 0.01 s (5 physics steps of 0.002 s,
short beside the arm's ~0.1 s response to a velocity command), so an episode lasts 20 s, of which a learned reach
takes well under one; the rest is holding still. (The thesis gives no control period; at 0.02 s the same T would
be 40 s of mostly holding, at twice the physics cost.)

Beyond the thesis: a dense reward (minus the summed end-point distances in metres, failure as above), random
targets in a box, varied starts (the neutral pose plus up to ±0.1 rad per joint), so that a policy must act on what
it observes rather than replay one trajectory, and a joint-target controller in front of the joint velocities.

Why the controller. With the thesis's actions (joint velocities) a linear policy has no restoring force: a
perturbation ε of its weights is a velocity that persists, and on both arms (574 weights, 14 joints) every candidate
of σ = 0.05 drove some joint into its limit within a second, so every candidate failed and the ranking only
rewarded failing later. Stopping each joint just inside its limits, as the real robot's controller does, is not
enough: the joints then drift to their stops and the arms into the table or each other (in a trial the centre
failed by contact in every episode after 200 real episodes, and reached nothing in 400). With
``controller="joint_targets"`` an action sets target angles, kept inside the limits, and a proportional controller
turns them into the joint velocities the robot is sent, as Baxter's position mode would: a perturbed policy moves
the targets, which the arm then holds, rather than a velocity that persists; no policy can drive a joint into its
limit, and contacts still fail the episode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from drrl.envs.baxter.kinematics import POINT_RADII, arms_points
from drrl.envs.baxter.model import ARM, SIDES, TABLE, TABLE_TOP, neutral_pose

CONTROL_PERIOD = 0.01  # seconds per action: 5 physics steps of 0.002 s
HORIZON = 2000  # control steps (thesis 5.10)
TOLERANCE = 0.05  # metres between end-point and target counted as "at the target"
START_NOISE = 0.1  # rad: each joint starts uniformly within ± this of the neutral pose
OFFSET_UNIT = 0.1  # metres: end-point-to-target offsets are observed in tenths of a metre
REWARDS = ("thesis", "dense")
CONTROLLERS = ("velocity", "joint_targets")
TARGET_SPAN = 1.5  # rad: a joint-target action of ±1 puts the joint's target this far from the neutral pose
LIMIT_MARGIN = 0.05  # rad: joint targets stay this far inside each joint's limits
TARGET_GAIN = 5.0  # 1/s: the joint-target controller's velocity command per radian from the target (0.2 s to close)
TARGET_MODES = ("fixed", "random")
# Imagined episodes (model-based runs) subtract this many times the end-point distances (m) from each step's reward.
# Under 5.10 alone every episode that neither reaches nor fails earns exactly −T: once the search in the model had
# learned not to fail, all its candidates tied and it had nothing to climb (one-arm reach, seed 1: the centre held
# still for 10 iterations). 0.1 ranks those episodes by how close they stay, while a step nearer the target by 1 m
# is still worth less than one step at it; real returns keep the thesis's reward.
TIE_BREAK = 0.1
# ... and this many times the joints' summed speeds (as fractions of their limits). A reach ends at rest, but 5.10 is
# blind to a joint that turns without moving the end-point, a wrist roll about the gripper's own axis: a policy found
# in 300-step imagined episodes spun it into its limit 600-1000 steps into the real ones (one-arm reach, seed 1).
# 0.1 keeps moving every joint at full speed cheaper than one step away from the target.
STILLNESS = 0.1

# Boxes in the base frame (metres) as (low corner, high corner), for the right arm; the left arm's are mirrored in y.
# WORKSPACE is where targets may lie: every point in it is reached by the end-point, away from the joint limits and
# free of collisions (checked by inverse kinematics in the tests); it stays 0.1 m above the table top.
WORKSPACE = ((0.45, -0.70, TABLE_TOP + 0.10), (0.85, 0.10, 0.45))
RANDOM_TARGETS = ((0.55, -0.55, -0.05), (0.80, -0.25, 0.20))  # the default box of random targets
FIXED_TARGET = (0.75, -0.40, 0.05)  # in front of the robot, 0.47 m from the neutral end-point


def mirror(point, side: str) -> np.ndarray:
    """A right-arm point as seen by ``side``: the left arm's is reflected in the x-z plane."""
    point = np.array(point, dtype=np.float64)
    if side == "left":
        point[..., 1] *= -1
    return point


def side_box(box, side: str) -> tuple[np.ndarray, np.ndarray]:
    """A right-arm box for ``side`` as (low, high) corners."""
    low, high = mirror(box[0], side), mirror(box[1], side)
    return np.minimum(low, high), np.maximum(low, high)


def check_in_workspace(points, side: str, what: str = "target") -> None:
    """Raise ValueError unless every point (..., 3) lies inside ``side``'s reachable workspace."""
    low, high = side_box(WORKSPACE, side)
    points = np.asarray(points, dtype=np.float64)
    if points.shape[-1:] != (3,) or not np.isfinite(points).all():
        raise ValueError(f"{what} for the {side} arm must be finite (x, y, z) points, got {points.tolist()}")
    outside = np.any((points < low) | (points > high), axis=-1)
    if outside.any():
        raise ValueError(
            f"{what} {points.reshape(-1, 3)[outside.reshape(-1)][0].tolist()} is outside the {side} "
            f"arm's reachable workspace, the box from {low.tolist()} to {high.tolist()} (metres, base "
            f"frame)"
        )


@dataclass(frozen=True)
class ReachTask:
    """Which arms move, where their targets are, how steps are rewarded and when episodes end.

    ``targets``: "fixed" puts each arm's target at ``fixed_target`` (the thesis's setting; right-arm coordinates,
    mirrored for the left arm); "random" draws it per episode uniformly from ``target_box``. Both must lie in
    ``WORKSPACE``. ``action_noise``: the commanded joint velocities get Gaussian noise of this many times each
    joint's velocity limit per control step (5.2.1: "the transition function follows physical law with some noise").
    ``controller``: "velocity", an action is each joint's angular velocity (5.2.1, the thesis's); "joint_targets", an
    action in [−1, 1] per joint sets its target angle ``TARGET_SPAN`` · action from the neutral pose (kept
    ``LIMIT_MARGIN`` inside its limits), and the command is ``TARGET_GAIN`` · (target − angle). Every command is then
    held within the joints' velocity limits.
    """

    arms: tuple[str, ...] = SIDES
    targets: str = "fixed"
    reward: str = "thesis"
    horizon: int = HORIZON
    tolerance: float = TOLERANCE
    fixed_target: tuple[float, float, float] = FIXED_TARGET
    target_box: tuple[tuple[float, float, float], tuple[float, float, float]] = RANDOM_TARGETS
    start_noise: float = START_NOISE
    action_noise: float = 0.0
    controller: str = "velocity"
    joint_low: np.ndarray = field(init=False, repr=False)
    joint_high: np.ndarray = field(init=False, repr=False)
    max_velocity: np.ndarray = field(init=False, repr=False)
    neutral: np.ndarray = field(init=False, repr=False)
    _last_points: list = field(default_factory=list, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "arms", tuple(self.arms))
        if not self.arms or len(set(self.arms)) != len(self.arms) or set(self.arms) - set(SIDES):
            raise ValueError(f"arms must be distinct sides among {SIDES}, got {self.arms!r}")
        _check_choice("targets", self.targets, TARGET_MODES)
        _check_choice("reward", self.reward, REWARDS)
        _check_choice("controller", self.controller, CONTROLLERS)
        if self.horizon < 1 or self.tolerance <= 0 or self.start_noise < 0 or self.action_noise < 0:
            raise ValueError("horizon and tolerance must be positive, start_noise and action_noise non-negative")
        for side in self.arms:
            check_in_workspace(mirror(self.fixed_target, side), side, "fixed_target")
            check_in_workspace(np.stack(side_box(self.target_box, side)), side, "target_box corner")
        arms = len(self.arms)
        object.__setattr__(self, "joint_low", np.tile([j.lower for j in ARM], arms))
        object.__setattr__(self, "joint_high", np.tile([j.upper for j in ARM], arms))
        object.__setattr__(self, "max_velocity", np.tile([j.max_velocity for j in ARM], arms))
        object.__setattr__(self, "neutral", np.concatenate([neutral_pose(side) for side in self.arms]))

    @property
    def num_joints(self) -> int:
        return 7 * len(self.arms)

    @property
    def observation_size(self) -> int:
        """Joint angles and velocities, then each target and each end-point-to-target offset."""
        return 2 * self.num_joints + 6 * len(self.arms)

    @property
    def random_numbers_per_start(self) -> int:
        """U[0, 1) numbers one start draws: a noise per joint, then 3 per random target."""
        return self.num_joints + (3 * len(self.arms) if self.targets == "random" else 0)

    def starts(self, uniform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start joint angles (n, joints) and targets (n, arms, 3) from U[0, 1) numbers, (n, random_numbers_per_start)
        of them."""
        joints = self.neutral + self.start_noise * (2 * uniform[:, : self.num_joints] - 1)
        n = len(uniform)
        if self.targets == "fixed":
            targets = np.broadcast_to([mirror(self.fixed_target, side) for side in self.arms], (n, len(self.arms), 3))
            return joints, targets.copy()
        boxes = [side_box(self.target_box, side) for side in self.arms]
        low, high = np.stack([box[0] for box in boxes]), np.stack([box[1] for box in boxes])
        fractions = uniform[:, self.num_joints :].reshape(n, len(self.arms), 3)
        return joints, low + (high - low) * fractions

    def observe(self, qpos, qvel, targets, end_points) -> np.ndarray:
        """Observations (n, observation_size), float32: joint angles (rad), joint velocities as fractions of their
        limits, targets (m) and end-point-to-target offsets in units of 0.1 m.

        The scaling keeps every entry of order one: PGPE explores every weight with the same σ, so an input ten
        times smaller than the others needs weights ten times larger. In short trials (dense reward, 300-step
        episodes) no setting we tried brought a linear policy to the target in 95 % of episodes within 1200
        episodes with offsets in metres and velocities in rad/s; with this scaling one did within 600.
        """
        n = len(qpos)
        offsets = (targets - end_points) / OFFSET_UNIT
        return np.concatenate(
            [qpos, qvel / self.max_velocity, targets.reshape(n, -1), offsets.reshape(n, -1)], axis=1, dtype=np.float32
        )

    def velocities(self, actions: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """The joint velocities (n, joints) that actions (n, joints) command at joint angles ``qpos``, before the
        velocity limits: the actions themselves ("velocity"), or the joint-target controller's command."""
        if self.controller == "velocity":
            return actions
        targets = self.neutral + TARGET_SPAN * actions
        return TARGET_GAIN * (np.clip(targets, self.joint_low + LIMIT_MARGIN, self.joint_high - LIMIT_MARGIN) - qpos)

    def at_limit(self, qpos: np.ndarray) -> np.ndarray:
        """Whether any joint has reached its position limit, (n,)."""
        return np.any((qpos <= self.joint_low) | (qpos >= self.joint_high), axis=1)

    def rewards(self, distances: np.ndarray, failed: np.ndarray, step) -> tuple[np.ndarray, np.ndarray]:
        """(reward (n,), terminated (n,)) after the transition at 1-based ``step``, from the end-point distances
        (n, arms) and failures (n,): 5.10 as read in this module's docstring, or the dense variant."""
        if self.reward == "thesis":
            reward = np.all(distances <= self.tolerance, axis=1) - 1.0
        else:
            reward = -distances.sum(axis=1)
        if failed.any():
            reward = np.where(failed, -2.0 * (self.horizon - np.asarray(step)), reward)
        return reward, failed.copy()

    # -------------------------------------------------- the task in closed form of an observation (imagined episodes)

    def observed_angles(self, observations: np.ndarray) -> np.ndarray:
        """The joint angles (n, joints) in observations (n, observation_size)."""
        return np.asarray(observations[:, : self.num_joints], dtype=np.float64)

    def observed_targets(self, observations: np.ndarray) -> np.ndarray:
        """The targets (n, arms, 3) in observations (n, observation_size)."""
        start, arms = 2 * self.num_joints, len(self.arms)
        return np.asarray(observations[:, start : start + 3 * arms], dtype=np.float64).reshape(-1, arms, 3)

    def complete_observation(self, previous: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """Predicted next observations (n, observation_size) with what follows from the rest: the targets of the
        previous observations (they stay put through an episode) and the end-point-to-target offsets through forward
        kinematics of the predicted joint angles. A world model that predicts every entry should have predicted
        these; taking them in closed form leaves it only the joints' dynamics to get right."""
        completed = np.array(predicted, dtype=np.float32)
        start, end = 2 * self.num_joints, 2 * self.num_joints + 3 * len(self.arms)
        completed[:, start:end] = previous[:, start:end]
        offsets = self.observed_targets(completed) - self.arm_points(self.observed_angles(completed))[:, :, 3]
        completed[:, end:] = offsets.reshape(len(completed), -1) / OFFSET_UNIT
        return completed

    def observed_reward(
        self, observations: np.ndarray, steps: np.ndarray, tie_break: float = 0.0, stillness: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reward and end (n,) of the transitions into ``observations`` at 1-based ``steps``, in closed form: the
        distances through forward kinematics, failure when a joint is at its limit or the arm reaches into the table
        (``touches_table``). Contacts with the body or the other arm are not checked: they need the link shapes.

        ``tie_break`` subtracts that many times the summed end-point distances (m) from every step's reward, so that
        episodes which never reach the target, all −1 a step under 5.10, are ranked by how close they came
        (``TIE_BREAK`` says why and how much); ``stillness`` that many times the joints' summed speeds, as fractions
        of their limits (``STILLNESS``)."""
        angles = self.observed_angles(observations)
        points = self.arm_points(angles)
        distances = np.linalg.norm(self.observed_targets(observations) - points[:, :, 3], axis=2)
        reward, ended = self.rewards(distances, self.at_limit(angles) | touches_table(points), steps)
        speeds = np.abs(observations[:, self.num_joints : 2 * self.num_joints]).sum(axis=1)
        return reward - tie_break * distances.sum(axis=1) - stillness * speeds, ended

    def arm_points(self, angles: np.ndarray) -> np.ndarray:
        """Elbow, wrist, hand and end-point of each arm (n, arms, 4, 3) for the joint angles (n, joints), not to be
        written to. The last answer is kept: an imagined step completes its observation and then rewards it, both
        from the same angles (the kinematics were 45 % of an imagined step)."""
        key = np.ascontiguousarray(angles, dtype=np.float64).tobytes()
        if not self._last_points or self._last_points[0] != key:
            self._last_points[:] = [key, arms_points(angles, self.arms)]
        return self._last_points[1]


def touches_table(points: np.ndarray) -> np.ndarray:
    """Whether any elbow, wrist, hand or end-point (n, arms, 4, 3) lies within its link's radius of the table top,
    over the table, (n,): the contact rule as far as it follows from the joint angles."""
    (x, y, _), (dx, dy, _) = TABLE["pos"], TABLE["size"]
    over = (np.abs(points[..., 0] - x) <= dx) & (np.abs(points[..., 1] - y) <= dy)
    return np.any(over & (points[..., 2] - POINT_RADII <= TABLE_TOP), axis=(1, 2))


def _check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")


# ---------------------------------------------------------------------------------------------------- verdict


def reach_fraction(final_distance: torch.Tensor, terminated: torch.Tensor, tolerance: float = TOLERANCE) -> float:
    """The fraction of episodes that ended (at the horizon, not by failure) with every end-point within
    ``tolerance`` of its target. ``final_distance``: each episode's largest end-point distance at its last step."""
    reached = (torch.as_tensor(final_distance) <= tolerance) & ~torch.as_tensor(terminated, dtype=torch.bool)
    return float(reached.double().mean())


def reach_verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
    """What a 5.10 return can tell, for metrics.csv and ``drrl eval``: an episode *held* its target(s) if it did not
    fail and spent at least half of the T = 2000 steps with every end-point within 0.05 m (return ≥ −1000, as each
    step away costs 1). held_95 / held_80: at least 95 % / 80 % of the episodes held (the bars for a fixed target /
    random targets); no_failure: no episode touched anything or hit a joint limit.

    The reach criterion proper, where an episode *ends*, needs the final distance, which a return does not hold:
    benchmarks/baxter_reach.py measures it with ``reach_fraction``. Assumes episodes of the full horizon (a
    ``max_steps`` cut shortens them and makes holding easier) and the thesis reward (not the dense one)."""
    held = (torch.as_tensor(episode_returns) >= -HORIZON / 2) & ~torch.as_tensor(terminated, dtype=torch.bool)
    fraction = float(held.double().mean())
    return {
        "held_95": fraction >= 0.95,
        "held_80": fraction >= 0.80,
        "no_failure": not bool(torch.as_tensor(terminated).any()),
    }


def explain_reach(episode_returns: torch.Tensor, terminated: torch.Tensor) -> str:
    kept = int((~torch.as_tensor(terminated, dtype=torch.bool)).sum())
    return (
        f"({kept}/{terminated.numel()} episodes without a failure; held: every end-point within 0.05 m of its "
        f"target for at least half of the episode)"
    )
